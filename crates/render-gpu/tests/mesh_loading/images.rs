//! EXR inputs: environment maps with bad pixels or huge declared sizes, and `merge`'s
//! refusal of one seed twice.

/// Environment maps with pixels the renderers cannot sum are refused by pixel.
#[test]
fn environment_maps_with_bad_pixels_are_refused() {
    use render_gpu::image_io::{RenderTag, RgbImage, write_exr};
    let d = tempfile::tempdir().unwrap();
    let tag = RenderTag {
        spp: 1,
        scene_hash: 0,
        seeds: Vec::new(),
        partial: false,
        unknown_digests: Vec::new(),
        view_hash: None,
    };
    let desc = |f: &str| render_gpu::scene::EnvironmentDesc {
        radiance: None,
        file: Some(f.into()),
    };
    let mut img = RgbImage::new(4, 2);
    img.pixels.fill([0.5; 3]);
    write_exr(&d.path().join("ok.exr"), &img, &tag).unwrap();
    assert!(render_gpu::light::Environment::new(&desc("ok.exr"), d.path()).is_ok());
    for (name, v) in [
        ("nan.exr", f32::NAN),
        ("neg.exr", -1.0),
        ("inf.exr", f32::INFINITY),
    ] {
        img.pixels[5] = [0.5, v, 0.5];
        write_exr(&d.path().join(name), &img, &tag).unwrap();
        let e = render_gpu::light::Environment::new(&desc(name), d.path())
            .err()
            .expect("a bad pixel is refused")
            .to_string();
        assert!(e.contains(name) && e.contains("pixel (1, 1)"), "{e}");
    }
    // A pixel beyond the bound is written short (3e38 was written out in 39 digits).
    img.pixels[5] = [0.5, 3e38, 0.5];
    write_exr(&d.path().join("huge.exr"), &img, &tag).unwrap();
    let e = render_gpu::light::Environment::new(&desc("huge.exr"), d.path())
        .err()
        .expect("a pixel beyond the bound is refused")
        .to_string();
    assert!(e.contains("pixel (1, 1) = 3e38 is out of range"), "{e}");
    // Pixels and scale each within the bound, their product beyond it (the variance's
    // squared sums overflowed f32 to inf): refused, naming the field and the file.
    img.pixels.fill([0.5; 3]);
    img.pixels[3] = [0.5, 1e12, 0.5];
    write_exr(&d.path().join("bright.exr"), &img, &tag).unwrap();
    let scaled = |r: f64| render_gpu::scene::EnvironmentDesc {
        radiance: Some([1.0, r, 1.0]),
        file: Some("bright.exr".into()),
    };
    assert!(render_gpu::light::Environment::new(&scaled(1.0), d.path()).is_ok());
    let e = render_gpu::light::Environment::new(&scaled(1e12), d.path())
        .err()
        .expect("a product beyond the bound is refused")
        .to_string();
    assert!(
        e.contains("bright.exr") && e.contains("environment.radiance[1]") && e.contains("1e12"),
        "{e}"
    );
}

/// An EXR whose header promises a huge image is refused before its pixels are allocated
/// (the reader allocates from the header's size alone; 10^9 × 10^9 would abort).
#[test]
fn exr_with_a_huge_declared_size_is_refused() {
    use render_gpu::image_io::{
        MAX_ENV_PIXELS, RenderTag, RgbImage, read_exr, read_exr_at_most, write_exr,
    };
    let d = tempfile::tempdir().unwrap();
    let path = d.path().join("huge.exr");
    let tag = RenderTag {
        spp: 1,
        scene_hash: 0,
        seeds: Vec::new(),
        partial: false,
        unknown_digests: Vec::new(),
        view_hash: None,
    };
    write_exr(&path, &RgbImage::new(4, 2), &tag).unwrap();
    assert!(read_exr(&path).is_ok());
    // The dataWindow attribute: name, type, size 16, then xMin, yMin, xMax, yMax (i32 LE).
    let mut bytes = std::fs::read(&path).unwrap();
    let key = b"dataWindow\0box2i\0";
    let at = bytes
        .windows(key.len())
        .position(|w| w == key)
        .expect("a dataWindow attribute")
        + key.len()
        + 4;
    // An environment map may be at most 2^26 pixels, less than a render (16,384², which
    // merge reads back): 16,384 × 4,097 is refused as a map, before allocation.
    let mut map = bytes.clone();
    map[at + 8..at + 12].copy_from_slice(&16_383i32.to_le_bytes());
    map[at + 12..at + 16].copy_from_slice(&4_096i32.to_le_bytes());
    std::fs::write(&path, map).unwrap();
    let Err(e) = read_exr_at_most(&path, MAX_ENV_PIXELS) else {
        panic!("refused")
    };
    let e = e.to_string();
    assert!(
        e.contains("16384 x 4097 pixels: allowed at most 67108864"),
        "{e}"
    );
    bytes[at + 8..at + 12].copy_from_slice(&1_000_000_000i32.to_le_bytes());
    bytes[at + 12..at + 16].copy_from_slice(&1_000_000_000i32.to_le_bytes());
    std::fs::write(&path, bytes).unwrap();
    let Err(e) = read_exr(&path) else {
        panic!("refused")
    };
    let e = e.to_string();
    assert!(
        e.contains("huge.exr") && e.contains("allowed at most"),
        "{e}"
    );
    // An empty file is said to be one (exr: "reference to missing bytes").
    std::fs::write(d.path().join("empty.exr"), b"").unwrap();
    let Err(e) = read_exr(&d.path().join("empty.exr")) else {
        panic!("refused")
    };
    assert!(
        e.to_string()
            .ends_with("empty.exr: cannot read EXR: the file is empty"),
        "{e}"
    );
}

/// `merge_exrs` refuses two renders of one seed (they share their samples: a copy, or the
/// seed rendered again at another spp), recognises seedless older files by their pixels,
/// but merges constant images (an unlit or out-of-view object gives the same pixels for
/// every seed) and renders of different seeds. The merged tag lists its inputs' seeds, so
/// a merge and one of its own inputs are refused too (they were once merged as 3 spp of
/// 2).
#[test]
fn merge_refuses_one_seed_twice_but_not_equal_constant_images() {
    use render_gpu::image_io::{RenderTag, RgbImage, merge_exrs, read_exr, write_exr};
    let d = tempfile::tempdir().unwrap();
    let put = |name: &str, v: f32, vary: bool, seeds: &[u64], spp: u64| {
        let mut img = RgbImage::new(4, 2);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = [v + if vary { i as f32 } else { 0.0 }; 3];
        }
        let path = d.path().join(name);
        let tag = RenderTag {
            spp,
            scene_hash: 7,
            seeds: seeds.to_vec(),
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: None,
        };
        write_exr(&path, &img, &tag).unwrap();
        assert_eq!(read_exr(&path).unwrap().1, Some(tag));
        path
    };
    let a = put("a.exr", 1.0, true, &[1], 4);
    let a8 = put("a8.exr", 2.0, true, &[1], 8);
    let b = put("b.exr", 3.0, true, &[2], 4);
    let Err(e) = merge_exrs(&[&a, &a8]) else {
        panic!("one seed twice")
    };
    let e = e.to_string();
    assert!(
        e.contains("shares seed 1 with") && e.contains("a8.exr"),
        "{e}"
    );
    let (img, tag) = merge_exrs(&[&a, &b]).unwrap();
    assert_eq!((tag.spp, &tag.seeds), (8, &vec![1, 2]));
    assert_eq!(img.pixels[0], [2.0; 3]);
    let ab = d.path().join("ab.exr");
    write_exr(&ab, &img, &tag).unwrap();
    let Err(e) = merge_exrs(&[&ab, &b]) else {
        panic!("a merge and its own input")
    };
    let e = e.to_string();
    assert!(
        e.contains("shares seed 2 with") && e.contains("ab.exr"),
        "{e}"
    );
    let c = put("c.exr", 5.0, true, &[3], 8);
    let (img, tag) = merge_exrs(&[&ab, &c]).unwrap();
    assert_eq!((tag.spp, tag.seeds), (16, vec![1, 2, 3]));
    assert_eq!(img.pixels[0], [3.5; 3]);
    // Seedless: equal varying pixels are one render; equal constant pixels are not.
    let old1 = put("old1.exr", 1.0, true, &[], 4);
    let old2 = put("old2.exr", 1.0, true, &[], 4);
    let Err(e) = merge_exrs(&[&old1, &old2]) else {
        panic!("a copy")
    };
    let e = e.to_string();
    assert!(e.contains("same render"), "{e}");
    let c1 = put("c1.exr", 0.5, false, &[], 4);
    let c2 = put("c2.exr", 0.5, false, &[], 4);
    assert!(merge_exrs(&[&c1, &c2]).is_ok());
    // A seedless input keeps the others' seeds (it cleared them: the merge of a and old3
    // could then take a again, and again, each time counting its samples once more).
    let old3 = put("old3.exr", 4.0, true, &[], 4);
    let (img, tag) = merge_exrs(&[&a, &old3]).unwrap();
    assert_eq!((&tag.seeds, tag.partial), (&vec![1], true));
    assert_eq!(tag.unknown_digests.len(), 1, "old3's pixels are recorded");
    let mixed = d.path().join("mixed.exr");
    write_exr(&mixed, &img, &tag).unwrap();
    assert_eq!(read_exr(&mixed).unwrap().1, Some(tag));
    let Err(e) = merge_exrs(&[&mixed, &a]) else {
        panic!("a merge with an unknown seed and its own known input")
    };
    assert!(e.to_string().contains("shares seed 1 with"), "{e}");
    // Nor its input of unknown seed, known again by its pixels, directly or inside
    // another merge.
    let Err(e) = merge_exrs(&[&mixed, &old3]) else {
        panic!("a merge and its own input of unknown seed")
    };
    let held = |e: &render_gpu::error::RenderError| {
        e.to_string()
            .contains("holds a render of unknown seed that")
            && e.to_string().contains("mixed.exr holds too")
    };
    assert!(held(&e), "{e}");
    let (img_b3, tag_b3) = merge_exrs(&[&b, &old3]).unwrap();
    let b3 = d.path().join("b3.exr");
    write_exr(&b3, &img_b3, &tag_b3).unwrap();
    let Err(e) = merge_exrs(&[&mixed, &b3]) else {
        panic!("old3 inside both merges")
    };
    assert!(held(&e), "{e}");
    assert_eq!(merge_exrs(&[&mixed, &b]).unwrap().1.seeds, vec![1, 2]);
}
