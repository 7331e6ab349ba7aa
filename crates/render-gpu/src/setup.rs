//! From a scene file to what the integrators read: geometry, lights, medium, and the
//! scene's identity hash (what `merge` compares).

use std::path::Path;

use crate::camera::Camera;
use crate::distance_grid::DistanceGrid;
use crate::error::RenderError;
use crate::geometry::Geometry;
use crate::hash::Fnv64;
use crate::light::{DirectionalLight, Environment};
use crate::mesh::{self, TriMesh};
use crate::scene::{BoundaryKind, MAX_SCENE_VALUE, MIN_OBJECT_SIZE, SceneFile, Shape};

/// The medium's boundary: index-matched, or a dielectric of index [`Self::ior`].
///
/// A struct, not an enum with a dataless index-matched variant: that variant left the f32
/// of the other one uninitialised, and the optimiser hoists `1/ior²` out of the path loop
/// (a division has no side effects), taken or not. On 2026-12-05 the leftover bits were a
/// subnormal (0x72f), and dividing by it took a microcode assist at every resumption of a
/// path: an index-matched k = 8 bunny ran ST-CVAE 15 % and PT 10 % slower, by other shares
/// in other builds (docs/BENCHMARKS.md, "Sixtieth session"). Here every byte is defined.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Boundary {
    /// The index of refraction; 1 when index-matched.
    ior: f32,
    dielectric: bool,
}

impl Boundary {
    /// No refraction, no reflection: the medium's index is the air's.
    pub const INDEX_MATCHED: Self = Self {
        ior: 1.0,
        dielectric: false,
    };

    /// A dielectric boundary of index of refraction `ior`.
    pub fn dielectric(ior: f32) -> Self {
        Self {
            ior,
            dielectric: true,
        }
    }

    /// The dielectric's index of refraction; None when index-matched.
    #[inline]
    pub fn ior(self) -> Option<f32> {
        self.dielectric.then_some(self.ior)
    }

    /// The factor on every NEE term of light scattered in the medium: 1/ior² with a
    /// dielectric boundary, 1 when index-matched. The one source of this convention for the
    /// CPU integrators and the WGSL kernels (`params.consts4.x`).
    ///
    /// Radiance that crosses into the medium is scaled by ior² (its cone narrows), and by
    /// 1/ior² on the way out. Paths refract with weight 1 (Fresnel picks reflection or
    /// refraction by probability), which is right for light that reaches a path through the
    /// surface, since every inside stretch of a camera path is paired with its way in and
    /// out. NEE brings a light in along its shadow ray instead: the Fresnel product along
    /// that ray carries the light's irradiance into the medium with no ior² (a beam's power
    /// is conserved), so the camera side's 1/ior² is left over. Without it a dielectric
    /// object's NEE was ior² too bright (2.25× at ior 1.5); camera paths start outside
    /// the object, so a path inside has always entered once more than it has left.
    pub fn nee_scale(self) -> f32 {
        match self.ior() {
            None => 1.0,
            Some(ior) => 1.0 / (ior * ior),
        }
    }
}

pub struct SceneData {
    pub geo: Geometry,
    /// The distance grid; built only for ST-CVAE.
    pub grid: Option<DistanceGrid>,
    pub camera: Camera,
    pub sigma_t: [f32; 3],
    pub albedo: [f32; 3],
    pub g: f32,
    pub boundary: Boundary,
    pub lights: Vec<DirectionalLight>,
    pub env: Environment,
    /// Hash of everything that defines the converged image, except spp and seed.
    pub hash: u64,
    /// Hash of what the image shows (camera, object, medium, boundary, lights,
    /// environment), whichever integrator renders it: `bench error` refuses an image of
    /// another view than its reference's, which the scene hash cannot tell (an ST-CVAE
    /// image and its PT reference always differ there).
    pub view_hash: u64,
    /// Notes about the scene for the command to print, one line each (overlapping mesh
    /// pieces, rendered as their union but slower than one closed surface).
    pub notes: Vec<String>,
}

/// The object's mesh as the scene file describes it.
pub fn object_mesh(scene: &SceneFile, scene_dir: &Path) -> Result<TriMesh, RenderError> {
    let o = &scene.object;
    let mut m = match (o.shape, &o.mesh) {
        (Some(Shape::Sphere), _) => mesh::sphere(o.radius.unwrap_or(0.5) as f32),
        (Some(Shape::Cube), _) => mesh::cube(o.size.unwrap_or(1.0) as f32),
        (Some(Shape::TorusKnot), _) => mesh::torus_knot(),
        (None, Some(p)) => {
            let path = scene_dir.join(p);
            // Named with its field: a missing mesh was only "cube.obj: cannot open the
            // mesh", which did not say where the name came from or where it was looked for.
            let what = format!(
                "the mesh of object.mesh = \"{}\" (a relative path is looked for in the \
                 scene file's folder)",
                p.display()
            );
            mesh::load_mesh_as(&path, &what)?
        }
        (None, None) => unreachable!("validated: shape or mesh"),
    };
    let name = match &o.mesh {
        Some(p) => scene_dir.join(p).display().to_string(),
        None => "object".to_string(),
    };
    if let Some(h) = o.height {
        m.normalise_height(h as f32)
            .map_err(|e| RenderError::Mesh(format!("{name}: {e}")))?;
    }
    m.check_scale(
        MIN_OBJECT_SIZE as f32,
        MAX_SCENE_VALUE as f32,
        o.height.map(|h| h as f32),
    )
    .map_err(|e| RenderError::Mesh(format!("{name}: {e}")))?;
    Ok(m)
}

/// The surface offset eps of the scene's object as the renderer places it (moved by
/// `recentre`), without building its geometry: what [`check_density`] needs to check
/// media before a run renders anything (`experiment`'s densities).
pub fn object_eps(scene: &SceneFile, scene_dir: &Path) -> Result<f32, RenderError> {
    let mut mesh = object_mesh(scene, scene_dir)?;
    recentre(&mut mesh);
    Ok(crate::geometry::spawn_offset(&mesh))
}

/// The densest sigma_t an object of surface offset `eps` takes ([`check_density`]).
pub fn max_sigma_t(eps: f32) -> f64 {
    crate::geometry::MAX_SPAWN_DEPTH as f64 / eps as f64
}

/// The medium must be thicker than the surface offset `eps` by a margin, or paths entering
/// it start too deep and the image comes out dark (black at σ_t 10⁶ on a unit sphere)
/// without a word.
pub fn check_density(sigma_t: [f64; 3], eps: f32) -> Result<(), RenderError> {
    for (i, &s) in sigma_t.iter().enumerate() {
        let depth = s * eps as f64;
        if s > max_sigma_t(eps) {
            return Err(RenderError::Scene(format!(
                "medium.sigma_t[{i}] = {} is too dense for this object: the renderer's \
                 surface offset ({:.3e}, {:e} of the object's largest coordinate or \
                 extent) would be {depth:.2} mean free paths deep and bias the image; \
                 allowed sigma_t <= {:.4e} here: the object's optical size (sigma_t \
                 times its largest coordinate or extent) is at most {:.0} mean free \
                 paths, so lower sigma_t or the object's size",
                scatter_sim::ranges::num(s),
                eps,
                crate::geometry::EPS,
                max_sigma_t(eps),
                crate::geometry::MAX_SPAWN_DEPTH / crate::geometry::EPS
            )));
        }
    }
    Ok(())
}

/// Moves the mesh so that its bounding box is centred at the origin when it lies farther
/// from the origin than its own extent (where its position, not its size, set the
/// tolerances); returns the shift (the renderer's origin in the scene file's frame, 0 for
/// a mesh left in place: the shipped shapes, every mesh scaled by `object.height`, and
/// any mesh about the origin render exactly as before).
fn recentre(mesh: &mut TriMesh) -> [f64; 3] {
    let (lo, hi) = mesh.bounds();
    let c = (lo.as_dvec3() + hi.as_dvec3()) * 0.5;
    let extent = (hi - lo).max_element() as f64;
    if c.abs().max_element() > extent {
        // In f64, then rounded once: the differences are at the new, smaller magnitude,
        // where f32 resolves finer than the file's positions did.
        for p in &mut mesh.positions {
            *p = (p.as_dvec3() - c).as_vec3();
        }
        c.to_array()
    } else {
        [0.0; 3]
    }
}

/// Objects thinner than the surface offset resolves are refused, and those whose edges it
/// may blur are noted. Paths start `eps` inside the surface they enter (2e-5 of the
/// object's largest coordinate or extent): a plate 1000 wide and 0.015 thick (offset 0.02) rendered as
/// background without a word. Slabs render exactly up to an offset of 0.9 of their
/// thickness (measured: plates 1000 and 10 wide, 0.022–0.2 thick, gave the same image),
/// but near edges a path can start beyond the side face next to it: a unit cube with an
/// offset of 0.02 rendered 0.27 % too transparent. The bounding box's thinnest side
/// stands for the thickness: an object thin along a slanted direction is not caught.
fn thin_object_check(geo: &Geometry) -> Result<Option<String>, RenderError> {
    let thinnest = (geo.hi - geo.lo).min_element();
    let ratio = geo.eps / thinnest;
    let most = |share: f32| share / crate::geometry::EPS;
    if ratio > MAX_OFFSET_OF_THICKNESS {
        return Err(RenderError::Scene(format!(
            "the object is too thin for its size: its bounding box is {thinnest:.4e} thick \
             where the renderer's surface offset ({:e} of its largest coordinate or extent) \
             is {:.4e}, so paths would start beyond its far side (allowed: an offset of at \
             most {MAX_OFFSET_OF_THICKNESS} of the thinnest side, i.e. a largest side at \
             most {:.0}× the thinnest for an object about the origin)",
            crate::geometry::EPS,
            geo.eps,
            most(MAX_OFFSET_OF_THICKNESS)
        )));
    }
    Ok((ratio > NOTE_OFFSET_OF_THICKNESS).then(|| {
        format!(
            "the object is thin for its size (its bounding box {thinnest:.4e} thick, its \
             largest side {:.0}× that, beyond {:.0}×): within the renderer's surface offset \
             ({:.4e}) of its edges, paths may start beyond the side face next to them and the \
             image there come out too transparent",
            (geo.hi - geo.lo).max_element() / thinnest,
            most(NOTE_OFFSET_OF_THICKNESS),
            geo.eps
        )
    }))
}

/// A note where more than [`crate::thin_walls::NOTE_AREA_SHARE`] of the surface lies
/// within the surface offset of a far side (`centre`: where the mesh was moved from, to
/// name the place in the scene's coordinates).
fn thin_walls_note(geo: &Geometry, centre: [f64; 3]) -> Option<String> {
    let w = crate::thin_walls::thin_walls(geo);
    (w.area_share > crate::thin_walls::NOTE_AREA_SHARE).then(|| {
        let at =
            w.at.map(|p| {
                let p = p.as_dvec3() + glam::DVec3::from_array(centre);
                format!(", such as at [{:.4}, {:.4}, {:.4}]", p.x, p.y, p.z)
            })
            .unwrap_or_default();
        format!(
            "{:.1} % of the object's surface lies within the renderer's surface offset \
             ({:.4e}) of a far side{at}: paths entering there start beyond that wall and pass \
             through it as air, so those parts render too transparent; thicken them beyond \
             {:.1e} (the offset is {:e} of the object's size: scaling it does not help)",
            100.0 * w.area_share,
            geo.eps,
            2.0 * geo.eps,
            crate::geometry::EPS
        )
    })
}

/// The surface offset's largest share of the object's thinnest bounding-box side: half
/// (slabs render exactly to 0.9 and vanish at 1; edges are biased well before).
pub const MAX_OFFSET_OF_THICKNESS: f32 = 0.5;

/// The share beyond which a thin object is noted (a cube at twice this was 0.27 % off).
pub const NOTE_OFFSET_OF_THICKNESS: f32 = 0.01;

impl SceneData {
    /// Builds everything; `with_grid` also builds (or loads from the cache) the distance
    /// grid. `extra_hash` identifies inputs outside the scene (e.g. the model file).
    pub fn build(
        scene: &SceneFile,
        scene_dir: &Path,
        with_grid: bool,
        extra_hash: &[u8],
    ) -> Result<Self, RenderError> {
        let mut mesh = object_mesh(scene, scene_dir)?;
        // A mesh far from the origin is moved to it in the renderer's frame: the surface
        // offset and the other tolerances grow with the mesh's largest coordinate (f32
        // rounding does), so a unit cube placed at x = 40,000 got an offset of 0.8 and
        // rendered 5.7 % too transparent, and at 51,000 not at all. Lights and the
        // environment are directions; the camera moves with the object.
        let centre = recentre(&mut mesh);
        let env = crate::light::Environment::new(&scene.environment, scene_dir)?;
        let (hash, view_hash) = scene_hashes(scene, &mesh, &env, centre, extra_hash);
        let unchecked = unchecked_pieces_note(&mesh);
        let geo = Geometry::new(mesh);
        let thin = thin_object_check(&geo)?;
        check_density(scene.medium.sigma_t, geo.eps)?;
        let mut notes: Vec<String> = geo
            .overlaps
            .iter()
            .map(|(i, j)| {
                format!(
                    "pieces {} and {} of the mesh overlap: rendered by their nesting, solids \
                     as their union and cavities as air (paths cross the faces within the \
                     medium, ST-CVAE's sphere steps stay clear of them); one closed surface \
                     renders faster",
                    i + 1,
                    j + 1
                )
            })
            .collect();
        notes.extend(unchecked);
        // The object's box already says it is thin as a whole; otherwise its walls may be.
        let walls = thin
            .is_none()
            .then(|| thin_walls_note(&geo, centre))
            .flatten();
        notes.extend(thin);
        notes.extend(walls);
        // Every path starts in air (the integrators trace camera rays from outside the
        // object); from inside, a camera's paths would be taken for entering ones and lit
        // as if in air, so the image would be wrong without any error.
        let mut cam_desc = scene.camera.clone();
        for (k, c) in centre.into_iter().enumerate() {
            cam_desc.origin[k] -= c;
            cam_desc.target[k] -= c;
        }
        let eye = cam_desc.origin.map(|v| v as f32);
        if geo.inside(glam::Vec3::from_array(eye)) {
            let o = scene.camera.origin;
            return Err(RenderError::Scene(format!(
                "camera.origin = [{}, {}, {}] lies inside the object: the camera must be \
                 outside it (in air)",
                o[0] as f32, o[1] as f32, o[2] as f32
            )));
        }
        let grid = with_grid
            .then(|| DistanceGrid::cached(&geo, scene.render.grid_resolution))
            .transpose()
            .map_err(RenderError::Scene)?;
        let m = &scene.medium;
        let mut camera = Camera::new(&cam_desc);
        camera.start_before(geo.lo, geo.hi);
        Ok(Self {
            geo,
            grid,
            camera,
            sigma_t: m.sigma_t.map(|v| v as f32),
            albedo: m.albedo.map(|v| v as f32),
            g: m.g as f32,
            boundary: match scene.boundary.kind {
                BoundaryKind::IndexMatched => Boundary::INDEX_MATCHED,
                BoundaryKind::Dielectric => {
                    Boundary::dielectric(scene.boundary.ior_or_default() as f32)
                }
            },
            lights: scene.lights.iter().map(DirectionalLight::new).collect(),
            env,
            hash,
            view_hash,
            notes,
        })
    }
}

/// The scene's hash, of what its image depends on (the settings its integrator reads, the
/// mesh, the map, the model and the estimating code), and its view hash, of the picture
/// alone (the same for every integrator).
fn scene_hashes(
    scene: &SceneFile,
    mesh: &TriMesh,
    env: &Environment,
    centre: [f64; 3],
    extra_hash: &[u8],
) -> (u64, u64) {
    let mut h = Fnv64::new();
    // What the image depends on, and nothing else: renders of one scene from two job
    // folders (the mesh named by another relative path) or with settings their
    // integrator never reads must merge. The mesh and map contents are hashed below.
    let mut ident = scene.clone();
    ident.render.spp = 0;
    ident.render.seed = 0;
    ident.object.mesh = ident.object.mesh.map(|_| "mesh".into());
    ident.environment.file = ident.environment.file.map(|_| "map".into());
    // A default written out is the default (ior = 1.5 on a dielectric, a black sky
    // given as radiance = [0, 0, 0]): the same image hashed apart, and `merge` and
    // `bench error` refused the pair. Both are hashed as resolved, so that a changed
    // default (scene.rs, outside the render-code hash) changes the hash too.
    if ident.boundary.kind == crate::scene::BoundaryKind::Dielectric {
        ident.boundary.ior = Some(ident.boundary.ior_or_default());
    }
    // (+ 0.0: a radiance written as -0.0, which the range check takes, hashed apart.)
    ident.environment.radiance = Some(ident.environment.radiance_or_default().map(|v| v + 0.0));
    // The object's size settings are in the mesh's positions, hashed below, and a
    // threshold left at its default is the default: equivalent files (radius = 0.5 on
    // the default sphere, min_tau = 1 written out) hashed apart, and `merge` refused
    // their renders.
    ident.object.radius = None;
    ident.object.size = None;
    ident.object.height = None;
    let unread = crate::scene::RenderDesc::default();
    let r = &mut ident.render;
    r.min_tau = Some(r.min_tau_or_default());
    r.exact_tau = Some(r.exact_tau_or_default());
    if r.integrator == crate::scene::IntegratorKind::Pt {
        r.grid_resolution = unread.grid_resolution;
        r.min_tau = None;
        r.max_tau = None;
        r.exact_tau = None;
    }
    if r.integrator == crate::scene::IntegratorKind::Pt || !r.nee {
        r.nee_samples = unread.nee_samples;
        r.exact_nee_samples = unread.exact_nee_samples;
        r.path_nee_rays = unread.path_nee_rays;
    }
    h.write(serde_json::to_string(&ident).unwrap_or_default().as_bytes());
    // The view hash leaves out every integrator setting (PT and ST-CVAE, with or
    // without NEE, all render the one picture) and the code and model that estimate it.
    let mut view = Fnv64::new();
    ident.render = unread;
    view.write(serde_json::to_string(&ident).unwrap_or_default().as_bytes());
    let mut both = |bytes: &[u8]| {
        h.write(bytes);
        view.write(bytes);
    };
    for p in &mesh.positions {
        for x in p.to_array() {
            both(&x.to_le_bytes());
        }
    }
    // Which vertices form each face, too: one vertex set cut into different triangles
    // is a different object.
    for t in &mesh.triangles {
        for i in t {
            both(&i.to_le_bytes());
        }
    }
    if let Some(m) = &env.map {
        // Its shape too: one pixel buffer read as 16×8 or as 32×4 lights the scene
        // differently.
        both(&(m.width as u64).to_le_bytes());
        both(&(m.height as u64).to_le_bytes());
        for px in &m.pixels {
            for v in px {
                both(&v.to_le_bytes());
            }
        }
    }
    h.write(extra_hash);
    // The renderer's own estimating code (build.rs): renders by builds that converge
    // to different images must not pass for renders of one scene.
    h.write(env!("STCVAE_RENDER_CODE").as_bytes());
    // The positions hashed are the moved ones: where the mesh was is part of the scene
    // (a cube at x = 40,000 and at 40,010 before one camera hashed alike and merged).
    // Nothing is added for an unmoved mesh, whose hash stays as it was.
    if centre != [0.0; 3] {
        for c in centre {
            h.write(&c.to_le_bytes());
            view.write(&c.to_le_bytes());
        }
    }
    (h.finish(), view.finish())
}

/// Says when the mesh has too many pieces or triangles for its pieces to be checked for
/// overlaps (or their nesting surveyed).
fn unchecked_pieces_note(mesh: &TriMesh) -> Option<String> {
    crate::mesh::unchecked_pieces(mesh).map(|n| {
        format!(
            "the mesh has {n} closed pieces and {} triangles: beyond {} pieces or {} \
             triangles they are not checked for overlaps, and an overlap would render \
             partly as air; join overlapping pieces into one closed surface{}",
            mesh.triangles.len(),
            crate::mesh::MAX_OVERLAP_PIECES,
            crate::mesh::MAX_OVERLAP_CHECK_TRIANGLES,
            if crate::mesh::nesting_unsurveyed(mesh) {
                format!(
                    "; beyond {} pairs of pieces whose boxes overlap, or {} pieces, their \
                     nesting is not surveyed either: each is solid, wound outward (a \
                     cavity would render as medium)",
                    crate::mesh::MAX_NESTING_PAIRS,
                    crate::mesh::MAX_NESTING_PIECES
                )
            } else {
                String::new()
            }
        )
    })
}

#[cfg(test)]
mod tests {
    use super::Boundary;

    /// The struct keeps the enum's meaning: only a dielectric has an index, and NEE's
    /// factor is 1/ior² for it, exactly 1 index-matched (the defined `ior` field of an
    /// index-matched boundary, 1, must not leak into `ior()`).
    #[test]
    fn a_boundary_reads_as_the_enum_it_replaced() {
        assert_eq!(Boundary::INDEX_MATCHED.ior(), None);
        assert_eq!(Boundary::INDEX_MATCHED.nee_scale(), 1.0);
        let b = Boundary::dielectric(1.5);
        assert_eq!(b.ior(), Some(1.5));
        assert_eq!(b.nee_scale(), 1.0 / 2.25);
        // A dielectric of the air's index is still a dielectric (Fresnel's 0 reflects
        // nothing, but the refraction code runs), not index-matched.
        assert_eq!(Boundary::dielectric(1.0).ior(), Some(1.0));
        assert_ne!(Boundary::dielectric(1.0), Boundary::INDEX_MATCHED);
    }

    /// Every source of this crate is in the render-code hash (build.rs: SOURCES,
    /// RENDER_FILES, or a direct child of RENDER_DIRS), or listed here as unable to change
    /// what a render converges to. watertight.rs (every ray cast) and the piece survey
    /// (which pieces overlap) were left out of the hash, so `merge` and the PT cache would
    /// have taken renders of builds that differed there as one scene's.
    #[test]
    fn every_source_that_decides_a_render_is_hashed() {
        const UNHASHED: [&str; 13] = [
            "src/lib.rs",      // module declarations
            "src/cache.rs",    // where cached grids and cones are kept (keyed by code)
            "src/error.rs",    // error types and their messages
            "src/hash.rs",     // the hash function, not what a render estimates
            "src/image_io.rs", // output files; an environment map's pixels are hashed
            // The parsed scene, hashed with its defaults resolved (MODEL_MAX_G, which decides
            // where ST-CVAE takes model steps, by the CLI's `thresholds_hash`).
            "src/scene.rs",
            "src/thin_walls.rs", // a note only
            // The mesh's positions and triangles, which `scene_hashes` hashes.
            "src/mesh/gltf_file.rs",
            "src/mesh/obj_file.rs",
            "src/mesh/ply_file.rs",
            "src/mesh/prepare.rs",
            "src/mesh/shapes.rs",
            "src/mesh/triangulate.rs",
        ];
        // What build.rs hashed, as it names them (relative to this crate).
        let hashed: Vec<&str> = env!("STCVAE_RENDER_FILES").split(';').collect();
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut missing = Vec::new();
        let mut sources = Vec::new();
        let mut stack = vec![root.join("src")];
        while let Some(dir) = stack.pop() {
            for e in std::fs::read_dir(&dir).unwrap() {
                let path = e.unwrap().path();
                if path.is_dir() {
                    stack.push(path);
                    continue;
                }
                let rel = path.strip_prefix(root).unwrap().components();
                let rel = rel
                    .map(|c| c.as_os_str().to_string_lossy())
                    .collect::<Vec<_>>()
                    .join("/");
                if !rel.ends_with(".rs") {
                    continue;
                }
                if !hashed.contains(&rel.as_str()) && !UNHASHED.contains(&rel.as_str()) {
                    missing.push(rel.clone());
                }
                sources.push(rel);
            }
        }
        missing.sort();
        assert!(
            missing.is_empty(),
            "not in build.rs's render-code hash nor listed as unhashed: {missing:?}"
        );
        // The list itself stays true: each entry a source of the crate, and not hashed.
        for u in UNHASHED {
            assert!(
                sources.iter().any(|s| s == u),
                "{u} is listed but not a source"
            );
            assert!(
                !hashed.contains(&u),
                "{u} is listed as unhashed but build.rs hashes it"
            );
        }
    }
}
