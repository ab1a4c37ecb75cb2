//! The reward terms of Table II, indexed by an enum: names, default weights and task masks live
//! here once; the formulas are small pure functions in `rewards.rs`.

/// Which task a term belongs to (its indicator mask).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TermGroup {
    /// Always active.
    Common,
    /// Times I_2 (quad mode).
    Quad,
    /// Times I_1 (biped mode).
    Biped,
    /// Times I_1 and the upright indicator.
    BipedUpright,
}

macro_rules! reward_terms {
    ($( $variant:ident => $name:literal, $weight:expr, $group:ident; )*) => {
        /// One reward term of Table II.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[repr(usize)]
        pub enum RewardTerm { $(
            #[doc = $name]
            $variant,
        )* }

        impl RewardTerm {
            /// Every term, in report order.
            pub const ALL: [RewardTerm; [$($name),*].len()] = [$(RewardTerm::$variant),*];
            /// Number of terms.
            pub const COUNT: usize = Self::ALL.len();

            /// Stable name, used in configs, specs and logs (`reward/<name>`).
            pub const fn name(self) -> &'static str {
                match self { $(RewardTerm::$variant => $name,)* }
            }

            /// Table II weight (before the multiplication by the policy dt).
            pub const fn default_weight(self) -> f32 {
                match self { $(RewardTerm::$variant => $weight,)* }
            }

            /// The task mask of this term.
            pub const fn group(self) -> TermGroup {
                match self { $(RewardTerm::$variant => TermGroup::$group,)* }
            }
        }
    };
}

reward_terms! {
    Termination => "termination", -2e-2, Common;
    Collision => "collision", -1.0, Common;
    AngVelXy => "ang_vel_xy", -5e-2, Common;
    DofVel => "dof_vel", -5e-4, Common;
    DofAcc => "dof_acc", -2e-7, Common;
    ActionRate => "action_rate", -1e-2, Common;
    ActionSmoothness => "action_smoothness", -1e-2, Common;
    Torques => "torques", -2e-4, Common;
    HipPos => "hip_pos", -1.0, Common;
    DofPosLimits => "dof_pos_limits", -1.0, Common;
    QuadTrackingLinVel => "quad_tracking_lin_vel", 2.0, Quad;
    QuadTrackingAngVel => "quad_tracking_ang_vel", 1.0, Quad;
    QuadBaseHeight => "quad_base_height", 1.0, Quad;
    QuadBaseAngle => "quad_base_angle", 2.0, Quad;
    QuadLinVelZ => "quad_lin_vel_z", -0.5, Quad;
    QuadPeriodicGait => "quad_periodic_gait", 1.5, Quad;
    QuadFootClearance => "quad_foot_clearance", 1.0, Quad;
    BipedTrackingLinVel => "biped_tracking_lin_vel", 2.0, BipedUpright;
    BipedTrackingAngVel => "biped_tracking_ang_vel", 1.0, BipedUpright;
    BipedBaseHeight => "biped_base_height", 1.0, Biped;
    BipedBaseAngle => "biped_base_angle", 1.0, Biped;
    BipedPeriodicGait => "biped_periodic_gait", 2.0, BipedUpright;
    BipedFootClearance => "biped_foot_clearance", 1.0, Biped;
    BipedRearLegs => "biped_rear_legs", -0.5, Biped;
    BipedUprightContacts => "biped_upright_contacts", 1.0, Biped;
    // Not in Table II (weight 0, the paper's task): 1 while anything but a foot (the head, a
    // thigh, a calf) touches the terrain in the biped mode. A CPU-sized run rests on its head or
    // kneels on its front shins as a third support and never walks; a recipe may price that
    // rest (docs/src/decisions/0009-biped-body-contact.md).
    BipedBodyContact => "biped_body_contact", 0.0, Biped;
    // Not in Table II (weight 0, the paper's task): how far the hip abductions can move the
    // stance feet sideways, per radian, as a share of `rewards.sideways_reach_target`. Nose
    // down, the abduction axis points at the ground, and a foot right under its hip cannot be
    // moved sideways at all; the biped did not learn to step sideways from there
    // (docs/src/decisions/0010-sideways-reach.md). A stance with the feet ahead of or behind the
    // hips can.
    BipedSidewaysReach => "biped_sideways_reach", 0.0, BipedUpright;
    // Not in Table II (weight 0, the paper's task): legged_gym's feet air time for the stance
    // feet, with the gait clock's swing (period x swing ratio) as its target and its cap. A
    // biped that shuffles, touching down three times per clock cycle, pays at every touchdown;
    // a swing as long as the clock's is free (docs/src/decisions/0040-feet-air-time-for-the-biped.md).
    BipedFeetAirTime => "biped_feet_air_time", 0.0, BipedUpright;
}

impl RewardTerm {
    /// The term with this name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }
}

/// Task and upright indicators of one env at one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Indicators {
    /// I_1: biped mode (or 1 under the "no task indicator" ablation).
    pub biped: f32,
    /// I_2: quad mode (or 1 under the ablation).
    pub quad: f32,
    /// I_up: pitch above the upright threshold (or 1 under the "no upright indicator" ablation).
    pub upright: f32,
}

impl Indicators {
    /// The mask applied to a term of `group`.
    pub fn mask(&self, group: TermGroup) -> f32 {
        match group {
            TermGroup::Common => 1.0,
            TermGroup::Quad => self.quad,
            TermGroup::Biped => self.biped,
            TermGroup::BipedUpright => self.biped * self.upright,
        }
    }
}
