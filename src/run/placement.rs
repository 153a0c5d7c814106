//! Overlapped splitting on several threads: where the re-prediction after
//! the kicks runs. Before the join it is spread over every thread; inside
//! it runs on the flight's thread, beside the gas step. Which is faster
//! depends on the machine more than on the model: on a 2-vCPU guest the
//! 2400 predictions of the jet bed took as long on two threads as on one,
//! and the flight then started on data the other core's cache held
//! (results/benchmarks.md, twenty-sixth session). So both places are timed
//! in the run itself, and the faster one is used.
//!
//! The results are the same bits either way (the predictions are pure
//! functions of the state, queued in slot order), so the choice may depend
//! on wall-clock time without making runs differ.

/// Steps in each round of trials: the first step of a round re-predicts
/// inside the join, the second before it, and the rest where the trials
/// were faster. Paired trials in consecutive steps time both places on
/// nearly the same state; the trial in the slower place costs about 1/16
/// of the difference per step. The first round, whose first steps carry
/// one-off costs, has no trials and re-predicts inside.
const ROUND_STEPS: u64 = 16;

/// Weight of the newest trial in each place's running mean: about the last
/// four rounds (64 steps) count.
const TRIAL_WEIGHT: f64 = 0.25;

/// Running means of the wall time (s) from the re-prediction's start to
/// the join's end, per place, from the trial steps only.
#[derive(Debug, Default)]
pub(super) struct PredictionPlacement {
    steps: u64,
    before: Option<f64>,
    inside: Option<f64>,
}

impl PredictionPlacement {
    /// Whether the coming step re-predicts before the join.
    pub(super) fn before_join(&self) -> bool {
        if self.steps < ROUND_STEPS {
            return false;
        }
        match self.steps % ROUND_STEPS {
            0 => false,
            1 => true,
            _ => matches!((self.before, self.inside), (Some(b), Some(i)) if b < i),
        }
    }

    /// Ends a step that re-predicted before the join (`before`) or not, in
    /// `seconds` (s) from the re-prediction's start to the join's end. A
    /// step that was to re-predict before the join but had nothing to
    /// predict times neither place. (Inside trials are not told whether
    /// anything was predicted: with gas kicks every step has predictions
    /// due, and the soft and hybrid models never predict before the join,
    /// so they stay inside.)
    pub(super) fn end_step(&mut self, before: bool, seconds: f64) {
        let trial = self.steps % ROUND_STEPS;
        if self.steps >= ROUND_STEPS && trial < 2 && (trial == 1) == before {
            let mean = if before {
                &mut self.before
            } else {
                &mut self.inside
            };
            *mean = Some(mean.map_or(seconds, |m| m + TRIAL_WEIGHT * (seconds - m)));
        }
        self.steps += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `rounds` rounds in which re-predicting before the join takes
    /// `before` s and inside it `inside` s; returns where the last round's
    /// steps after its two trials re-predicted (true: before).
    fn run_rounds(p: &mut PredictionPlacement, rounds: u64, before: f64, inside: f64) -> Vec<bool> {
        let mut last_round = Vec::new();
        for _ in 0..rounds {
            last_round.clear();
            for step in 0..ROUND_STEPS {
                let b = p.before_join();
                if step >= 2 {
                    last_round.push(b);
                }
                p.end_step(b, if b { before } else { inside });
            }
        }
        last_round
    }

    #[test]
    fn the_faster_place_is_used_between_trials() {
        let rest = ROUND_STEPS as usize - 2;
        let mut p = PredictionPlacement::default();
        // The first round: no trials, inside (the one-thread path).
        assert_eq!(run_rounds(&mut p, 1, 1.0e-3, 2.0e-3), vec![false; rest]);
        assert_eq!((p.before, p.inside), (None, None));
        assert_eq!(run_rounds(&mut p, 2, 1.0e-3, 2.0e-3), vec![true; rest]);
        let mut p = PredictionPlacement::default();
        assert_eq!(run_rounds(&mut p, 3, 2.0e-3, 1.0e-3), vec![false; rest]);
    }

    #[test]
    fn the_trials_follow_a_change() {
        let rest = ROUND_STEPS as usize - 2;
        let mut p = PredictionPlacement::default();
        run_rounds(&mut p, 4, 1.0e-3, 2.0e-3);
        // Now before takes 3 ms and inside 1.5 ms. After k more trials the
        // means are 3 − 2·0.75^k and 1.5 + 0.5·0.75^k (ms): before is
        // still the faster after one round (1.5 against 1.875) and the
        // slower after two (1.875 against 1.78).
        assert_eq!(run_rounds(&mut p, 1, 3.0e-3, 1.5e-3), vec![true; rest]);
        assert_eq!(run_rounds(&mut p, 1, 3.0e-3, 1.5e-3), vec![false; rest]);
    }

    #[test]
    fn a_trial_with_nothing_to_predict_times_nothing() {
        let mut p = PredictionPlacement::default();
        run_rounds(&mut p, 1, 1.0, 1.0);
        p.end_step(false, 5.0e-3);
        // The round's second step was to re-predict before the join but
        // had nothing to predict: it is no trial.
        p.end_step(false, 1.0);
        assert_eq!((p.before, p.inside), (None, Some(5.0e-3)));
    }
}
