//! The distance grid is conservative: for random interior points the ball of the
//! returned radius never crosses the mesh (checked against exact BVH distance and rays).

mod common;

use std::path::Path;

use glam::Vec3;
use render_gpu::distance_grid::DistanceGrid;
use render_gpu::geometry::Geometry;
use render_gpu::mesh::{self, load_mesh};
use scatter_sim::WalkRng;

fn check(geo: &Geometry, grid: &DistanceGrid, points: usize, seed: u64) -> f64 {
    let mut rng = WalkRng::for_walk(seed, 0);
    let (mut sum_r, mut sum_d) = (0.0, 0.0);
    for _ in 0..points {
        let p = common::random_interior(geo, &mut rng);
        let r = grid.radius(p);
        let d = geo.distance(p);
        assert!(r <= d, "radius {r} exceeds the true distance {d} at {p}");
        for _ in 0..8 {
            let dir = common::uniform_direction(&mut rng);
            if let Some(h) = geo.intersect(p, dir, r) {
                panic!(
                    "a ray from {p} meets the mesh at t = {} inside the radius {r}",
                    h.t
                );
            }
        }
        sum_r += r as f64;
        sum_d += d as f64;
    }
    sum_r / sum_d
}

#[test]
fn bunny_grid_is_conservative_and_useful() {
    let m =
        load_mesh(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/bunny.ply")).unwrap();
    let geo = Geometry::new(m);
    let grid = DistanceGrid::build(&geo, 48);
    let efficiency = check(&geo, &grid, 3000, 11);
    // Not trivially conservative: at 48 cells the Lipschitz bound keeps most of the
    // distance (a cell's half-diagonal is ~2% of the bunny's height).
    assert!(
        efficiency > 0.7,
        "grid keeps only {efficiency:.2} of the true distance"
    );
}

#[test]
fn sphere_grid_matches_the_radius() {
    let geo = Geometry::new(mesh::sphere(0.5));
    let grid = DistanceGrid::build(&geo, 32);
    check(&geo, &grid, 1000, 12);
    // At the centre the free radius is the sphere's minus at most twice a cell's
    // half-diagonal (0.5·√3/32 ≈ 0.027: once in d(c) ≥ d(p) − |p − c|, once in the bound
    // d(c) − |p − c|) and the tessellation's chord error (< 3e-4).
    let r = grid.radius(Vec3::ZERO);
    assert!(r > 0.5 - 2.0 * 0.0271 - 3e-4 && r <= 0.5, "r(0) = {r}");
    assert_eq!(grid.radius(Vec3::splat(2.0)), 0.0, "outside the grid");
}
