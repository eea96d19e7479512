//! The firmware's acceptance test of one plan direction, which the host planner re-runs before it
//! sends a plan (Klipper's `check_line`): the same f32 code on both sides, so they agree exactly.

use crate::kinematics::{Kinematics, Steps, Unreachable};
use crate::msg::Direction;
use crate::separation::SeparationGuard;

/// The step targets that measure `d`, planned from the step positions `from`, or why it cannot be.
pub fn check_direction(
    kin: &Kinematics<f32>,
    guard: &SeparationGuard,
    d: &Direction,
    from: &Steps,
) -> Result<Steps, Unreachable> {
    let current = kin.from_steps(from);
    let pose = kin.inverse_angles(d.theta_i, d.phi_i, d.theta_o, d.phi_o, &current)?;
    let steps = kin.to_steps(&pose)?;
    // Rounding to steps may push an axis past a soft limit: check the pose actually reached.
    kin.check_pose(&kin.from_steps(&steps))?;
    if !guard.allows_target(&steps) {
        return Err(Unreachable::Blocked);
    }
    Ok(steps)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::instrument::InstrumentConfig;

    fn reference() -> (Kinematics<f32>, SeparationGuard) {
        let kin = Kinematics::new(InstrumentConfig::<f32>::reference()).unwrap();
        let guard = SeparationGuard::new(&kin);
        (kin, guard)
    }

    fn dir(theta_i: f32, theta_o: f32, phi_o: f32) -> Direction {
        Direction {
            theta_i,
            phi_i: 0.0,
            theta_o,
            phi_o,
        }
    }

    #[test]
    fn an_accepted_direction_is_measured_at_legal_targets() {
        let (kin, guard) = reference();
        let steps = check_direction(&kin, &guard, &dir(0.6, 0.4, 2.0), &[0; 4]).unwrap();
        assert!(guard.allows_target(&steps));
        assert!(kin.check_pose(&kin.from_steps(&steps)).is_ok());
    }

    #[test]
    fn a_direction_below_the_horizon_is_refused() {
        let (kin, guard) = reference();
        let got = check_direction(&kin, &guard, &dir(0.6, 1.7, 2.0), &[0; 4]);
        assert!(
            matches!(got, Err(Unreachable::BelowHorizon { incoming: false })),
            "{got:?}"
        );
    }

    #[test]
    fn the_retro_reflection_is_blocked_by_the_arms() {
        let (kin, guard) = reference();
        let got = check_direction(&kin, &guard, &dir(0.6, 0.6, 0.0), &[0; 4]);
        assert_eq!(got, Err(Unreachable::Blocked));
    }
}
