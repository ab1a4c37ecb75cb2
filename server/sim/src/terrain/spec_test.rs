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
    assert!((s.slope(9).atan().to_degrees() - 30.0).abs() < 1e-4);
    assert_eq!(s.slope(0), 0.0);
    assert!((s.step_height_at(5) - 0.15).abs() < 1e-6);
    assert!((s.step_height_at(9) - 0.23).abs() < 1e-6);
    assert!((s.obstacle_height_at(9) - 0.25).abs() < 1e-6);
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
