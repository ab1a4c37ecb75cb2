//! The curriculum rule and the per-step distances, on hand-computed episodes.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::*;

/// The default spec's rule: up above 70 % of the commanded distance and 2 m, down below 50 %.
const RULE: LevelRule = LevelRule {
    promote_share: 0.7,
    promote_min_distance: 2.0,
    demote_share: 0.5,
    promote_share_biped: 0.7,
    demote_share_biped: 0.5,
    per_mode_levels: false,
    judge_reach: false,
    promote_min_reach: 0.0,
};

const DT: f32 = 0.02;
/// 18 s at 50 Hz.
const EPISODE: usize = 900;

fn level_after(current: u32, walked: f32, commanded: f32) -> u32 {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    next_level(
        current,
        EpisodeDistance {
            walked,
            commanded,
            commanded_biped: 0.0,
            walked_biped: 0.0,
            ..EpisodeDistance::default()
        },
        &RULE,
        10,
        &mut rng,
    )
}

/// `steps` steps of `command` walked at `velocity`.
fn walk(d: &mut EpisodeDistance, steps: usize, command: [f32; 2], velocity: [f32; 2]) {
    for _ in 0..steps {
        d.add_step(command, velocity, DT, false);
    }
}

#[test]
fn a_biped_walking_most_of_its_command_is_promoted() {
    // 0.35 m/s for 18 s under 0.4 m/s: walked 6.3 m of 7.2 m (87.5 % > 70 %, > 2 m).
    let mut d = EpisodeDistance::default();
    walk(&mut d, EPISODE, [0.4, 0.0], [0.35, 0.0]);
    assert!((d.walked - 6.3).abs() < 1e-3, "{d:?}");
    assert!((d.commanded - 7.2).abs() < 1e-3, "{d:?}");
    assert_eq!(level_after(3, d.walked, d.commanded), 4);
    // legged_gym's rule (4 m from the spawn point) promotes it only if it walked straight.
}

#[test]
fn reversed_commands_count_in_full() {
    // Forward 0.4 m/s for 6 s, then backward 0.4 m/s for 6 s, tracked exactly: it ends where it
    // started (legged_gym would demote it: 0 m < half of 0.4 x 18 s), but walked 4.8 m of 4.8.
    let mut d = EpisodeDistance::default();
    walk(&mut d, 300, [0.4, 0.0], [0.4, 0.0]);
    walk(&mut d, 300, [-0.4, 0.0], [-0.4, 0.0]);
    assert!((d.walked - 4.8).abs() < 1e-3 && (d.commanded - 4.8).abs() < 1e-3);
    assert_eq!(level_after(3, d.walked, d.commanded), 4);
    // Sideways drift does not count; walking against the command counts negative.
    let mut d = EpisodeDistance::default();
    walk(&mut d, 100, [0.3, 0.4], [0.8, -0.6]);
    assert!(d.walked.abs() < 1e-4, "{d:?}");
    assert!((d.commanded - 1.0).abs() < 1e-4);
    let mut d = EpisodeDistance::default();
    walk(&mut d, 100, [0.5, 0.0], [-0.5, 0.0]);
    assert!((d.walked + 1.0).abs() < 1e-4);
}

#[test]
fn standing_does_not_promote() {
    // A zero command asks for nothing and adds nothing, whatever the body does.
    let mut d = EpisodeDistance::default();
    walk(&mut d, EPISODE, [0.0, 0.0], [0.3, 0.0]);
    assert_eq!(d, EpisodeDistance::default());
    assert_eq!(level_after(3, d.walked, d.commanded), 3);
    // An episode that asked for little (1.6 m: mostly standing commands, or cut short) is not
    // promoted even when tracked well (1.5 m, 94 %): below the 2 m minimum.
    assert_eq!(level_after(3, 1.5, 1.6), 3);
    // Standing under a 0.4 m/s command: demoted.
    let mut d = EpisodeDistance::default();
    walk(&mut d, EPISODE, [0.4, 0.0], [0.0, 0.0]);
    assert_eq!(level_after(3, d.walked, d.commanded), 2);
}

#[test]
fn walking_a_fifth_of_the_command_is_demoted_and_between_stays() {
    // 20 % of 7.2 m = 1.44 m < 3.6 m: down.
    assert_eq!(level_after(3, 1.44, 7.2), 2);
    // 60 % (4.32 m): neither above 70 % nor below 50 %.
    assert_eq!(level_after(3, 4.32, 7.2), 3);
    // A quad at 1 m/s: 13 m of 18 m (72 %) up, 10 m (56 %) stays.
    assert_eq!(level_after(3, 13.0, 18.0), 4);
    assert_eq!(level_after(3, 10.0, 18.0), 3);
    // Level 0 is the floor.
    assert_eq!(level_after(0, 0.0, 10.0), 0);
}

#[test]
fn a_fall_is_judged_on_the_full_episode() {
    // Walked 1.2 m of 1.2 m in 3 s, then fell: the 15 s left count as 6 m asked and not walked,
    // so 1.2 m of 7.2 m (17 %): down, not up.
    let mut d = EpisodeDistance::default();
    walk(&mut d, 150, [0.4, 0.0], [0.4, 0.0]);
    assert_eq!(level_after(3, d.walked, d.commanded), 3);
    d.add_unlived([0.4, 0.0], 15.0, false);
    assert!((d.commanded - 7.2).abs() < 1e-3);
    assert_eq!(level_after(3, d.walked, d.commanded), 2);
}

#[test]
fn passing_the_top_level_sends_to_a_random_level() {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let up = EpisodeDistance {
        walked: 5.0,
        commanded: 5.0,
        commanded_biped: 0.0,
        walked_biped: 0.0,
        ..EpisodeDistance::default()
    };
    let mut seen = [false; 10];
    for _ in 0..500 {
        let l = next_level(9, up, &RULE, 10, &mut rng);
        assert!(l < 10);
        seen[l as usize] = true;
    }
    assert!(seen.iter().all(|s| *s));
    // Below the top: a plain step up.
    assert_eq!(next_level(8, up, &RULE, 10, &mut rng), 9);
}

#[test]
fn columns_are_filled_in_blocks() {
    let columns: Vec<u32> = (0..14).map(|i| initial_column(i, 14, 7)).collect();
    assert_eq!(columns, [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6]);
    // Fewer envs than columns: spread out, never past the last column.
    let few: Vec<u32> = (0..3).map(|i| initial_column(i, 3, 7)).collect();
    assert_eq!(few, [0, 2, 4]);
    assert_eq!(initial_column(99, 3, 7), 4);
}

/// The biped's lines: 0.6 to move up, 0.3 to move down, on the distance asked for on two legs.
const BIPED_RULE: LevelRule = LevelRule {
    promote_share_biped: 0.6,
    demote_share_biped: 0.3,
    ..RULE
};

fn level_under(rule: &LevelRule, current: u32, d: EpisodeDistance) -> u32 {
    next_level(current, d, rule, 10, &mut ChaCha8Rng::seed_from_u64(0))
}

#[test]
fn each_mode_is_judged_against_its_own_line() {
    // Two legs for 18 s at 65 % of a 0.4 m/s command (as the terrain run's biped on flat
    // ground): 4.68 m of 7.2 m. One line for both modes keeps it where it is; the biped's own
    // line (0.6) moves it up.
    let mut d = EpisodeDistance::default();
    for _ in 0..EPISODE {
        d.add_step([0.4, 0.0], [0.26, 0.0], DT, true);
    }
    assert!((d.commanded_biped - 7.2).abs() < 1e-3 && (d.commanded - 7.2).abs() < 1e-3);
    assert!((d.walked - 4.68).abs() < 1e-3, "{d:?}");
    assert_eq!(level_under(&RULE, 3, d), 3);
    assert_eq!(level_under(&BIPED_RULE, 3, d), 4);
    // At 40 % (2.88 m): down under one line, kept above the biped's 0.3.
    let slow = EpisodeDistance { walked: 2.88, ..d };
    assert_eq!(level_under(&RULE, 3, slow), 2);
    assert_eq!(level_under(&BIPED_RULE, 3, slow), 3);
    // Mixed: 6 s on four legs at 1 m/s walking 4.5 m (75 %), then 12 s on two at 0.4 m/s walking
    // 2.9 m (60 %): 7.4 m of 10.8 m (69 %) stays under one line; the per-mode line is
    // 0.7 x 6 + 0.6 x 4.8 = 7.08 m, so it moves up.
    let mut d = EpisodeDistance::default();
    for _ in 0..300 {
        d.add_step([1.0, 0.0], [0.75, 0.0], DT, false);
    }
    for _ in 0..600 {
        d.add_step([0.4, 0.0], [0.4 * 2.9 / 4.8, 0.0], DT, true);
    }
    assert!((d.commanded - 10.8).abs() < 1e-3 && (d.commanded_biped - 4.8).abs() < 1e-3);
    assert!((d.walked - 7.4).abs() < 1e-3, "{d:?}");
    assert!((d.line(0.7, 0.6) - 7.08).abs() < 1e-3);
    assert_eq!(level_under(&RULE, 3, d), 3);
    assert_eq!(level_under(&BIPED_RULE, 3, d), 4);
    // A fall on two legs counts the rest of the episode as asked of the biped.
    let mut d = EpisodeDistance::default();
    d.add_unlived([0.3, 0.4], 10.0, true);
    assert!((d.commanded_biped - 5.0).abs() < 1e-4 && d.walked == 0.0);
}

/// Decision record 0036: one mode's part of a mixed episode, judged as if it were the whole.
#[test]
fn a_mode_is_judged_on_its_own_part_of_the_episode() {
    // 6 s on four legs at 0.8 m/s stalled at a riser (1.2 m of 4.8 m), then 12 s on two at
    // 0.4 m/s climbing at 0.32 m/s (3.84 m of 4.8 m).
    let mut d = EpisodeDistance::default();
    for _ in 0..300 {
        d.add_step([0.8, 0.0], [0.2, 0.0], DT, false);
    }
    for _ in 0..600 {
        d.add_step([0.0, -0.4], [0.0, -0.32], DT, true);
    }
    assert!(
        (d.walked - 5.04).abs() < 1e-3 && (d.walked_biped - 3.84).abs() < 1e-3,
        "{d:?}"
    );
    let quad = d.in_mode(false);
    assert!((quad.walked - 1.2).abs() < 1e-3 && (quad.commanded - 4.8).abs() < 1e-3);
    assert_eq!((quad.commanded_biped, quad.walked_biped), (0.0, 0.0));
    let biped = d.in_mode(true);
    assert!((biped.walked - 3.84).abs() < 1e-3 && (biped.commanded - 4.8).abs() < 1e-3);
    assert_eq!(biped.commanded_biped, biped.commanded);
    // Together (5.04 m of 9.6 m, 53 %) the env stays; the quad's 25 % moves its level down,
    // the biped's 80 % (and 3.84 m >= 2 m) moves its level up.
    assert_eq!(level_under(&RULE, 3, d), 3);
    assert_eq!(level_under(&RULE, 3, quad), 2);
    assert_eq!(level_under(&RULE, 3, biped), 4);
}

#[test]
fn the_rule_is_checked_field_by_field() {
    LevelRule::default().validate().expect("the default");
    BIPED_RULE.validate().expect("the biped's own lines");
    for (rule, field) in [
        (
            LevelRule {
                promote_share_biped: 1.5,
                ..RULE
            },
            "terrain_curriculum.promote_share_biped",
        ),
        // Demoting above the promotion line would move an env both ways.
        (
            LevelRule {
                demote_share_biped: 0.8,
                ..RULE
            },
            "terrain_curriculum.demote_share_biped",
        ),
        (
            LevelRule {
                demote_share: 0.8,
                ..RULE
            },
            "terrain_curriculum.demote_share",
        ),
        (
            LevelRule {
                promote_min_distance: -1.0,
                ..RULE
            },
            "terrain_curriculum.promote_min_distance",
        ),
        (
            LevelRule {
                promote_min_reach: f32::NAN,
                ..RULE
            },
            "terrain_curriculum.promote_min_reach",
        ),
    ] {
        let err = rule.validate().expect_err(field).to_string();
        assert!(err.contains(field), "{err}");
    }
}

/// `RULE` with the reach judged (decision record 0038).
const REACH_RULE: LevelRule = LevelRule {
    judge_reach: true,
    ..RULE
};

/// Legs of `steps` steps, each at heading `yaw` (rad) and `speed` (m/s) in the robot's own
/// frame, under a straight forward command of `command` m/s: the base's offset from the spawn
/// point is integrated here, apart from `Reach`'s commanded path.
fn walk_legs(d: &mut EpisodeDistance, legs: &[(usize, f32, f32)], command: f32, biped: bool) {
    let mut at = [0.0f32, 0.0];
    for &(steps, yaw, speed) in legs {
        for _ in 0..steps {
            at[0] += yaw.cos() * speed * DT;
            at[1] += yaw.sin() * speed * DT;
            d.add_step([command, 0.0], [speed, 0.0], DT, biped);
            d.reach.add_step(at, yaw, [command, 0.0, 0.0], DT, biped);
        }
    }
}

/// The probe behind decision record 0038: told to walk straight at 0.4 m/s, the biped reaches
/// the first riser, turns and paces along it at full speed. It tracks its command in its own
/// frame (7.2 m of 7.2) and gets no farther than 1.56 m from its spawn point.
#[test]
fn a_robot_that_paces_along_a_riser_is_judged_by_its_reach() {
    use std::f32::consts::FRAC_PI_2;
    let mut d = EpisodeDistance::default();
    // 1.2 m out along x, then 1 m along +y, then 2 m back and forth along the riser (x = 1.2).
    let legs = [
        (150, 0.0, 0.4),
        (125, FRAC_PI_2, 0.4),
        (250, -FRAC_PI_2, 0.4),
        (250, FRAC_PI_2, 0.4),
        (125, -FRAC_PI_2, 0.4),
    ];
    walk_legs(&mut d, &legs, 0.4, true);
    assert!(
        (d.walked - 7.2).abs() < 1e-3 && (d.commanded - 7.2).abs() < 1e-3,
        "{d:?}"
    );
    let reach = 1.2f32.hypot(1.0);
    assert!((d.reach.walked[1] - reach).abs() < 1e-3, "{:?}", d.reach);
    assert!((d.reach.commanded[1] - 7.2).abs() < 1e-3, "{:?}", d.reach);
    assert!((d.reach.share() - reach / 7.2).abs() < 1e-4);
    // Walked alone it is promoted; judged by its reach (1.56 m of 7.2, under the 3.6 m
    // demotion line) it goes down, on the biped's own lines too.
    assert_eq!(level_under(&RULE, 3, d), 4);
    assert_eq!(level_under(&REACH_RULE, 3, d), 2);
    assert_eq!(
        level_under(
            &LevelRule {
                judge_reach: true,
                ..BIPED_RULE
            },
            3,
            d
        ),
        2
    );
    assert_eq!(level_under(&REACH_RULE, 3, d.in_mode(true)), 2);
}

/// A robot that follows its commands, turns included, is judged on what it walked, as before.
#[test]
fn following_the_commanded_path_keeps_the_walked_distance() {
    // 18 s on an arc: 0.8 m/s at a commanded 0.3 rad/s, walked at 0.8 x 0.75 with the yaw rate
    // tracked, from heading 0.5 rad. The base's offset is the arc's closed form.
    let (speed, wz, yaw0) = (0.6f32, 0.3f32, 0.5f32);
    let mut d = EpisodeDistance::default();
    for k in 1..=EPISODE {
        let t = k as f32 * DT;
        let yaw = yaw0 + wz * t;
        let at = [
            speed / wz * (yaw.sin() - yaw0.sin()),
            speed / wz * (yaw0.cos() - yaw.cos()),
        ];
        d.add_step([0.8, 0.0], [speed, 0.0], DT, false);
        d.reach
            .add_step(at, yaw - wz * DT, [0.8, 0.0, wz], DT, false);
    }
    // Both arcs turn 5.4 rad, past half a turn, so each gets a diameter from the spawn point:
    // the walked one on a 2 m radius, the commanded one on 8/3 m.
    let far = |radius: f32| 2.0 * radius;
    assert!((d.reach.walked[0] - far(2.0)).abs() < 0.01, "{:?}", d.reach);
    assert!(
        (d.reach.commanded[0] - far(8.0 / 3.0)).abs() < 0.02,
        "{:?}",
        d.reach
    );
    assert!((d.reach.share() - 0.75).abs() < 0.01);
    // 10.8 m of 14.4 (75 %): promoted under either rule.
    assert!((d.walked - 10.8).abs() < 1e-2, "{d:?}");
    assert_eq!(level_under(&RULE, 3, d), 4);
    assert_eq!(level_under(&REACH_RULE, 3, d), 4);
}

/// A mode switch restarts the commanded path at the base: the quad's stall at a riser is
/// charged to the quad's level, not to the biped that walks on from there.
#[test]
fn one_modes_shortfall_is_not_charged_to_the_other() {
    let mut d = EpisodeDistance::default();
    walk_legs(&mut d, &[(300, 0.0, 0.2)], 0.8, false);
    // The biped goes on along x from 1.2 m.
    let mut at = [1.2f32, 0.0];
    for _ in 0..600 {
        at[0] += 0.32 * DT;
        d.add_step([0.4, 0.0], [0.32, 0.0], DT, true);
        d.reach.add_step(at, 0.0, [0.4, 0.0, 0.0], DT, true);
    }
    assert!((d.reach.walked[0] - 1.2).abs() < 1e-3 && (d.reach.commanded[0] - 4.8).abs() < 1e-3);
    // Restarted at 1.2 m, the biped's commanded path reaches 6.0 m, its base 5.04 m.
    assert!((d.reach.walked[1] - 5.04).abs() < 1e-3, "{:?}", d.reach);
    assert!((d.reach.commanded[1] - 6.0).abs() < 1e-3, "{:?}", d.reach);
    let (quad, two) = (d.in_mode(false), d.in_mode(true));
    assert!((quad.reach.share() - 0.25).abs() < 1e-4);
    assert!((two.reach.share() - 0.84).abs() < 1e-4);
    // The quad's 25 % moves its level down, the biped's 80 % up, under either rule.
    for rule in [&RULE, &REACH_RULE] {
        assert_eq!(level_under(rule, 3, quad), 2);
        assert_eq!(level_under(rule, 3, two), 4);
    }
}

#[test]
fn a_reach_ignores_non_finite_steps_and_an_empty_command() {
    let mut r = Reach::default();
    r.add_step([f32::NAN, 0.0], 0.0, [0.4, 0.0, 0.0], DT, false);
    assert_eq!(r, Reach::default());
    // Standing still under no command: nothing asked, nothing charged.
    for _ in 0..100 {
        r.add_step([0.0, 0.0], 0.0, [0.0, 0.0, 0.0], DT, false);
    }
    assert_eq!(r.share(), 1.0);
}

/// Decision record 0038, its second part: a slow command asks little, so a biped that climbs two
/// risers and stalls there can make a share of it. Told 0.15 m/s for 18 s (2.7 m), it walks
/// straight out 2.3 m and stands: 85%, promoted under the reach rule alone; with a minimum reach
/// of 4 m (half a tile, legged_gym's promotion) it stays. One that gets 4.2 m out is promoted.
#[test]
fn a_promotion_needs_the_reach_asked_for() {
    let rule = LevelRule {
        promote_min_reach: 4.0,
        ..REACH_RULE
    };
    let mut stalled = EpisodeDistance::default();
    walk_legs(
        &mut stalled,
        &[(767, 0.0, 0.15), (133, 0.0, 0.0)],
        0.15,
        true,
    );
    assert!(
        (stalled.reach.farthest() - 2.3).abs() < 1e-2,
        "{:?}",
        stalled.reach
    );
    assert!((stalled.commanded - 2.7).abs() < 1e-3);
    assert_eq!(level_under(&REACH_RULE, 3, stalled), 4);
    assert_eq!(level_under(&rule, 3, stalled), 3);
    let mut far = EpisodeDistance::default();
    walk_legs(&mut far, &[(900, 0.0, 0.2333)], 0.25, true);
    assert!((far.reach.farthest() - 4.2).abs() < 1e-2, "{:?}", far.reach);
    assert_eq!(level_under(&rule, 3, far), 4);
    assert_eq!(level_under(&rule, 3, far.in_mode(true)), 4);
}
