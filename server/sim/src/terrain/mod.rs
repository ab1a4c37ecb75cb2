//! Terrains: the shape robots walk on, its rapier collider, and fast height queries.

use rapier3d::math::Vec3;
use rapier3d::prelude::{ColliderBuilder, SharedShape};

/// A terrain shared by every robot of a world.
#[derive(Clone, Debug, PartialEq)]
pub enum Terrain {
    /// An infinite plane at z = 0.
    Flat,
}

impl Terrain {
    /// Terrain height at (x, y) (m).
    #[inline]
    pub fn height(&self, _x: f32, _y: f32) -> f32 {
        match self {
            Terrain::Flat => 0.0,
        }
    }

    /// Unit surface normal at (x, y).
    #[inline]
    pub fn normal(&self, _x: f32, _y: f32) -> Vec3 {
        match self {
            Terrain::Flat => Vec3::Z,
        }
    }

    /// Highest terrain point within `radius` of (x, y) (m), sampled at the centre and 8 points
    /// on the circle.
    #[inline]
    pub fn max_height_within(&self, x: f32, y: f32, radius: f32) -> f32 {
        match self {
            Terrain::Flat => 0.0,
            #[allow(unreachable_patterns)]
            _ => {
                let mut h = self.height(x, y);
                for k in 0..8 {
                    let a = k as f32 * std::f32::consts::FRAC_PI_4;
                    h = h.max(self.height(x + radius * a.cos(), y + radius * a.sin()));
                }
                h
            }
        }
    }

    /// The rapier collider of this terrain (for a fixed body at the origin).
    pub fn collider(&self) -> ColliderBuilder {
        match self {
            Terrain::Flat => ColliderBuilder::new(SharedShape::halfspace(Vec3::Z)),
        }
    }

    /// Spawn origin (x, y) of env `index` of `count`. On flat ground the envs stand on a grid 3 m
    /// apart so recordings are readable (robots never collide with each other anyway).
    pub fn env_origin(&self, index: usize, count: usize) -> (f32, f32) {
        let cols = (count as f32).sqrt().ceil().max(1.0) as usize;
        let spacing = 3.0;
        (
            (index % cols) as f32 * spacing,
            (index / cols) as f32 * spacing,
        )
    }
}
