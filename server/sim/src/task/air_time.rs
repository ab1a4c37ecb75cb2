//! How long each foot was in the air before it touched down: legged_gym's feet-air-time
//! bookkeeping (decision record 0040).

use crate::robot::NUM_FEET;

/// Per-foot air time across policy steps.
///
/// A contact counts if the foot touches now or touched at the previous step (legged_gym's
/// `contact_filt`: a foot's contact force flickers on uneven ground), so one bounce does not
/// end a swing twice.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FeetAirTime {
    /// Seconds each foot has been off the ground, up to this step.
    air: [f32; NUM_FEET],
    /// Raw contacts of the previous step.
    last_contact: [bool; NUM_FEET],
}

impl FeetAirTime {
    /// Advance one policy step of `dt` seconds with this step's contacts. Returns, per foot,
    /// the air time of a swing that ended at this step (its first contact), else 0.
    pub fn step(&mut self, contact: [bool; NUM_FEET], dt: f32) -> [f32; NUM_FEET] {
        let mut touchdown = [0.0; NUM_FEET];
        for f in 0..NUM_FEET {
            let down = contact[f] || self.last_contact[f];
            let first = down && self.air[f] > 0.0;
            self.air[f] += dt;
            if first {
                touchdown[f] = self.air[f];
            }
            if down {
                self.air[f] = 0.0;
            }
            self.last_contact[f] = contact[f];
        }
        touchdown
    }
}

#[cfg(test)]
mod test {
    use super::*;

    const DT: f32 = 0.02;

    fn run(steps: &[[bool; NUM_FEET]]) -> Vec<[f32; NUM_FEET]> {
        let mut t = FeetAirTime::default();
        steps.iter().map(|&c| t.step(c, DT)).collect()
    }

    #[test]
    fn a_swing_of_n_steps_touches_down_with_n_plus_one_steps_of_air() {
        // legged_gym adds the step's dt before it reads the first contact.
        let (up, down) = ([false; NUM_FEET], [true; NUM_FEET]);
        let out = run(&[down, up, up, up, down, down]);
        assert_eq!(
            out[0], [0.0; NUM_FEET],
            "standing from the start: no swing ended"
        );
        assert!(
            out[1..4].iter().all(|t| *t == [0.0; NUM_FEET]),
            "the step after a contact counts as down"
        );
        // Up at steps 1-3, but step 1 is filtered down by step 0's contact: air at steps 2
        // and 3, ended at step 4 with its own dt: 3 steps.
        for (f, air) in out[4].iter().enumerate() {
            assert!((air - 3.0 * DT).abs() < 1e-6, "foot {f}: {air}");
        }
        assert_eq!(out[5], [0.0; NUM_FEET], "a foot still down ends nothing");
    }

    #[test]
    fn a_one_step_flicker_is_no_swing() {
        let mut c = [true; NUM_FEET];
        c[1] = false;
        let out = run(&[[true; NUM_FEET], c, [true; NUM_FEET], c, [true; NUM_FEET]]);
        assert!(out.iter().all(|t| *t == [0.0; NUM_FEET]), "{out:?}");
    }

    #[test]
    fn each_foot_keeps_its_own_clock() {
        let mut a = [true; NUM_FEET];
        a[0] = false; // FL in the air for 4 steps, FR for 2
        let mut b = a;
        b[1] = false;
        let out = run(&[[true; NUM_FEET], a, a, b, b, a, [true; NUM_FEET]]);
        // FR: down at 0-2, air at 3-4 (step 3 filtered by step 2), touches at 5: 2 steps.
        assert!((out[5][1] - 2.0 * DT).abs() < 1e-6, "{out:?}");
        // FL: up from step 1, filtered at 1, air 2-5, touches at 6: 5 steps.
        assert!((out[6][0] - 5.0 * DT).abs() < 1e-6, "{out:?}");
        assert_eq!(out[6][2], 0.0);
    }
}
