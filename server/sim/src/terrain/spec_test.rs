//! Spec defaults, names, ranges and serialisation.

use super::*;

#[test]
fn defaults_are_valid_and_reach_the_papers_test_terrain() {
    let s = TerrainSpec::default();
    s.validate().expect("valid");
    assert_eq!(s.kind, TerrainKind::Flat);
    assert_eq!(s.cells_per_tile(), 80);
    assert_eq!(s.step_cells(), 3);
    assert_eq!(s.platform_cells(), 30);
    assert_eq!(s.slope(0), 0.0);
    assert!((s.slope(9).atan().to_degrees() - 37.0).abs() < 1e-4);
    assert!((s.step_height_at(9) - 0.20).abs() < 1e-6);
    assert!((s.obstacle_height_at(9) - 0.25).abs() < 1e-6);
}

/// The level at which each of the paper's Table VI terrains is first met, before (one column per
/// type, 30 deg linear in angle, steps [0.05, 0.23] m) and after; printed with `--nocapture`.
#[test]
fn table_vi_terrains_come_before_the_top_level() {
    let before = TerrainSpec {
        types: TerrainType::ALL.to_vec(),
        max_slope_deg: 30.0,
        step_height: [0.05, 0.23],
        ..TerrainSpec::default()
    };
    let after = TerrainSpec::default();
    // The old slope rule: the angle linear in d.
    let old_deg = |l: u32| 30.0 * before.difficulty(l);
    let new_deg = |l: u32| after.slope(l).atan().to_degrees();
    println!("level | step before / after (m) | slope before / after (deg)");
    for l in 0..10 {
        println!(
            "{l:5} | {:.3} / {:.3} | {:.1} / {:.1}",
            before.step_height_at(l),
            after.step_height_at(l),
            old_deg(l),
            new_deg(l)
        );
    }
    let first = |ok: &dyn Fn(u32) -> bool| (0..10).find(|&l| ok(l));
    // 15 cm stairs: level 5 before, level 6 after (exactly 0.15 m), with 0.20 m at the top.
    assert_eq!(first(&|l| before.step_height_at(l) >= 0.15 - 1e-6), Some(5));
    assert_eq!(first(&|l| after.step_height_at(l) >= 0.15 - 1e-6), Some(6));
    // 12 cm (the biped's stairs up): level 4 before (0.13 m), level 5 after (0.133 m).
    assert_eq!(first(&|l| after.step_height_at(l) >= 0.12), Some(5));
    // 30 deg: only the top level before; level 7 after (30.4 deg), 37 deg at the top.
    assert_eq!(first(&|l| old_deg(l) >= 30.0 - 1e-4), Some(9));
    assert_eq!(first(&|l| new_deg(l) >= 30.0), Some(7));
    assert!((new_deg(7) - 30.37).abs() < 0.01);
    assert!((new_deg(8) - 33.81).abs() < 0.01);
}

/// Stairs (up + down) take 60 % of the default columns (legged_gym's 0.35 + 0.25), against
/// 2 of 7 (29 %) with one column per type.
#[test]
fn default_columns_follow_legged_gyms_proportions() {
    let cols = TerrainSpec::default().types;
    assert_eq!(cols.len(), 20);
    let share = |ts: &[TerrainType]| {
        cols.iter().filter(|t| ts.contains(t)).count() as f32 / cols.len() as f32
    };
    let stairs = [TerrainType::StairsUp, TerrainType::StairsDown];
    assert_eq!(share(&[TerrainType::SlopeUp, TerrainType::SlopeDown]), 0.1);
    assert_eq!(share(&[TerrainType::RoughSlope]), 0.1);
    assert_eq!(share(&[TerrainType::StairsUp]), 0.35);
    assert_eq!(share(&[TerrainType::StairsDown]), 0.25);
    assert_eq!(share(&[TerrainType::Obstacles]), 0.2);
    assert_eq!(share(&stairs), 0.6);
    let old = TerrainType::ALL;
    let old_stairs = old.iter().filter(|t| stairs.contains(t)).count();
    assert_eq!((old_stairs, old.len()), (2, 7));
    println!(
        "stairs: {:.0} % of columns before, {:.0} % after",
        100.0 * old_stairs as f32 / old.len() as f32,
        100.0 * share(&stairs)
    );
    // Same type, contiguous columns: the first of each is where DEFAULT_COLUMNS puts it.
    let spec = TerrainSpec::default();
    assert_eq!(spec.column_of(TerrainType::StairsUp), Some(4));
    assert_eq!(spec.column_of(TerrainType::StairsDown), Some(11));
    assert_eq!(spec.column_of(TerrainType::Obstacles), Some(16));
    assert_eq!(spec.column_of(TerrainType::Flat), None);
}

#[test]
fn type_names_round_trip() {
    for t in TerrainType::ALL {
        assert_eq!(TerrainType::from_name(t.name()), Some(t));
        assert_eq!(t.to_string(), t.name());
    }
    assert_eq!(TerrainType::from_name("lava"), None);
    let names: Vec<&str> = TerrainType::ALL.iter().map(|t| t.name()).collect();
    assert_eq!(
        names,
        [
            "flat",
            "slope_up",
            "slope_down",
            "rough_slope",
            "stairs_up",
            "stairs_down",
            "obstacles"
        ]
    );
}

#[test]
fn toml_round_trip_and_partial_documents() {
    let spec = TerrainSpec {
        kind: TerrainKind::Pinned {
            terrain_type: TerrainType::StairsUp,
            level: 5,
        },
        ..TerrainSpec::default()
    };
    let text = toml::to_string(&spec).expect("serialise");
    let back: TerrainSpec = toml::from_str(&text).expect("parse");
    assert_eq!(back, spec);
    let partial: TerrainSpec =
        toml::from_str("kind = { curriculum = { max_init_level = 3 } }\nnum_levels = 6")
            .expect("parse");
    assert_eq!(partial.kind, TerrainKind::Curriculum { max_init_level: 3 });
    assert_eq!(partial.num_levels, 6);
    assert_eq!(partial.tile_size, 8.0);
    assert!(toml::from_str::<TerrainSpec>("tile_sise = 8.0").is_err());
}

fn rejected(spec: TerrainSpec, field: &str) {
    match spec.validate() {
        Err(SimError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
        other => panic!("{field}: expected a config error, got {other:?}"),
    }
}

#[test]
fn bad_values_are_rejected_with_their_field() {
    let d = TerrainSpec::default;
    rejected(
        TerrainSpec {
            num_levels: 0,
            ..d()
        },
        "terrain.num_levels",
    );
    rejected(
        TerrainSpec {
            types: vec![],
            ..d()
        },
        "terrain.types",
    );
    rejected(
        TerrainSpec {
            tile_size: 8.05,
            ..d()
        },
        "terrain.tile_size",
    );
    rejected(
        TerrainSpec {
            tile_size: f32::NAN,
            ..d()
        },
        "terrain.tile_size",
    );
    rejected(
        TerrainSpec {
            horizontal_scale: 0.0,
            ..d()
        },
        "terrain.horizontal_scale",
    );
    rejected(
        TerrainSpec {
            border: -1.0,
            ..d()
        },
        "terrain.border",
    );
    rejected(
        TerrainSpec {
            step_height: [0.2, 0.1],
            ..d()
        },
        "terrain.step_height",
    );
    rejected(
        TerrainSpec {
            max_slope_deg: 80.0,
            ..d()
        },
        "terrain.max_slope_deg",
    );
    rejected(
        TerrainSpec {
            platform_size: 9.0,
            ..d()
        },
        "terrain.platform_size",
    );
    rejected(
        TerrainSpec {
            collider: TerrainCollider::Heightfield { subdivisions: 0 },
            ..d()
        },
        "terrain.collider.heightfield.subdivisions",
    );
    rejected(
        TerrainSpec {
            kind: TerrainKind::Curriculum { max_init_level: 10 },
            ..d()
        },
        "terrain.kind.curriculum.max_init_level",
    );
    rejected(
        TerrainSpec {
            kind: TerrainKind::Pinned {
                terrain_type: TerrainType::Obstacles,
                level: 0,
            },
            types: vec![TerrainType::Flat],
            ..d()
        },
        "terrain.kind.pinned.terrain_type",
    );
    rejected(
        TerrainSpec {
            kind: TerrainKind::Pinned {
                terrain_type: TerrainType::Flat,
                level: 10,
            },
            ..d()
        },
        "terrain.kind.pinned.level",
    );
}

#[test]
fn a_single_level_is_the_hardest() {
    let s = TerrainSpec {
        num_levels: 1,
        ..TerrainSpec::default()
    };
    assert_eq!(s.difficulty(0), 1.0);
    assert_eq!(s.difficulty(0), TerrainSpec::default().difficulty(9));
}
