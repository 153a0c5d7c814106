//! Overlapped splitting on several threads: where the re-prediction after
//! the kicks runs. Before the join it is spread over every thread; inside
//! it runs on the flight's thread, beside the gas step. Which is faster
//! depends on the machine more than on the model: on a 2-vCPU guest the
//! 2400 predictions of the jet bed took as long on two threads as on one,
//! and the riser's re-prediction before the join cost 2 ms a step more
//! than inside it (results/benchmarks.md, twenty-sixth session). So both
//! places are timed in the run itself, and the faster one is used.
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

/// Paired trials the choice looks back on: the median of their
/// differences decides, so that one step slowed by something else (the
/// host, a file written) does not move the re-prediction for a round.
const TRIALS_KEPT: usize = 5;

/// The paired trials of the two places and the choice they make. A
/// trial's difference (s) is the wall time from the re-prediction's start
/// to the join's end when it ran before the join, minus that when it ran
/// inside it, one step earlier.
#[derive(Debug, Default)]
pub(super) struct PredictionPlacement {
    steps: u64,
    /// This round's trial inside the join (s), until its pair is timed.
    inside: Option<f64>,
    /// The last [`TRIALS_KEPT`] differences, oldest overwritten first.
    differences: [f64; TRIALS_KEPT],
    trials: usize,
}

impl PredictionPlacement {
    /// Whether the coming step re-predicts before the join: at a round's
    /// second step (a trial), and at its other steps once
    /// [`TRIALS_KEPT`] paired trials say before is faster.
    pub(super) fn before_join(&self) -> bool {
        if self.steps < ROUND_STEPS {
            return false;
        }
        match self.steps % ROUND_STEPS {
            0 => false,
            1 => true,
            _ => self.trials >= TRIALS_KEPT && self.median_difference() < 0.0,
        }
    }

    /// Ends a step that re-predicted before the join (`before`) or not, in
    /// `seconds` (s) from the re-prediction's start to the join's end. A
    /// step that was to re-predict before the join but had nothing to
    /// predict completes no pair. (Inside trials are not told whether
    /// anything was predicted: with gas kicks every step has predictions
    /// due, and the soft and hybrid models never predict before the join,
    /// so they stay inside.)
    pub(super) fn end_step(&mut self, before: bool, seconds: f64) {
        if self.steps >= ROUND_STEPS {
            match (self.steps % ROUND_STEPS, before) {
                (0, false) => self.inside = Some(seconds),
                (1, true) => {
                    if let Some(inside) = self.inside.take() {
                        self.differences[self.trials % TRIALS_KEPT] = seconds - inside;
                        self.trials += 1;
                    }
                }
                _ => {}
            }
        }
        self.steps += 1;
    }

    /// Median of the kept differences (s; all [`TRIALS_KEPT`] of them).
    fn median_difference(&self) -> f64 {
        let mut d = self.differences;
        d.sort_by(f64::total_cmp);
        d[TRIALS_KEPT / 2]
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

    const REST: usize = ROUND_STEPS as usize - 2;

    #[test]
    fn the_faster_place_is_used_once_enough_trials_agree() {
        let mut p = PredictionPlacement::default();
        // The first round has no trials; then TRIALS_KEPT rounds of them
        // before anything but inside is chosen.
        for _ in 0..TRIALS_KEPT {
            assert_eq!(run_rounds(&mut p, 1, 1.0e-3, 2.0e-3), vec![false; REST]);
        }
        assert_eq!(p.trials, TRIALS_KEPT - 1);
        assert_eq!(run_rounds(&mut p, 1, 1.0e-3, 2.0e-3), vec![true; REST]);
        let mut p = PredictionPlacement::default();
        assert_eq!(run_rounds(&mut p, 8, 2.0e-3, 1.0e-3), vec![false; REST]);
    }

    #[test]
    fn the_trials_follow_a_change_by_majority() {
        let mut p = PredictionPlacement::default();
        run_rounds(&mut p, 8, 1.0e-3, 2.0e-3);
        // Inside becomes the faster: the median of the last five
        // differences turns positive with the third new trial.
        assert_eq!(run_rounds(&mut p, 1, 3.0e-3, 1.5e-3), vec![true; REST]);
        assert_eq!(run_rounds(&mut p, 1, 3.0e-3, 1.5e-3), vec![true; REST]);
        assert_eq!(run_rounds(&mut p, 1, 3.0e-3, 1.5e-3), vec![false; REST]);
    }

    #[test]
    fn one_outlying_trial_does_not_move_the_re_prediction() {
        let mut p = PredictionPlacement::default();
        run_rounds(&mut p, 8, 3.0e-3, 2.0e-3);
        // One round in which the inside trial was slowed by something else.
        assert_eq!(run_rounds(&mut p, 1, 3.0e-3, 9.0e-3), vec![false; REST]);
        assert_eq!(run_rounds(&mut p, 1, 3.0e-3, 2.0e-3), vec![false; REST]);
    }

    #[test]
    fn a_before_trial_with_nothing_to_predict_completes_no_pair() {
        let mut p = PredictionPlacement::default();
        run_rounds(&mut p, 1, 1.0, 1.0);
        p.end_step(false, 5.0e-3);
        // The round's second step was to re-predict before the join but
        // had nothing to predict, so it ran as inside.
        p.end_step(false, 1.0);
        assert_eq!(p.trials, 0);
    }
}
