//! End-to-end checks of `stcvae generate` and `stcvae merge` through the binary.

mod common;

use std::fs;
use std::process::Output;

use common::{stcvae, stderr, words};
use scatter_sim::dataset::read_dataset;

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "stcvae failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn fixed_condition_csv() {
    let dir = tempfile::tempdir().unwrap();
    let out = stcvae(
        &[
            "generate",
            "--samples",
            "500",
            "--tau",
            "5",
            "--g",
            "0.4",
            "--albedo",
            "1.0",
            "--seed",
            "7",
            "--out",
            "walks.csv",
        ],
        dir.path(),
    );
    ok(&out);
    let text = fs::read_to_string(dir.path().join("walks.csv")).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("tau,g,albedo,n,cos_theta,beta,alpha,ev_x,ev_y,ev_z,ev_wx,ev_wy,ev_wz")
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 500);
    for r in rows {
        let f: Vec<&str> = r.split(',').collect();
        assert_eq!(f.len(), 13);
        assert_eq!(
            &f[..3],
            ["5", "0.4", "1"],
            "conditions repeat the requested values"
        );
        assert!(f[3].parse::<u32>().unwrap() >= 1);
    }
}

/// `generate` and `sample` of one seed draw independent walks: the model's random numbers
/// are a stream apart from the simulator's. With one stream for both, row i of the two
/// files shared numbers (the simulator's first deflection and the decoders' first latent
/// values), and the paired rows correlated: over these 200,000 rows the event's y
/// position at z = 13.5 and its z direction at z = 19.
///
/// Statistic: per column, the Pearson correlation r of the paired rows; for independent
/// pairs r·√n is standard normal for large n whatever the columns' distributions (finite
/// variances suffice). Bar |z| < 5 for each of the ≤ 10 varying columns: a false alarm has
/// probability 10 · 5.7·10⁻⁷ ≈ 6·10⁻⁶.
#[test]
fn generate_and_sample_of_one_seed_are_independent() {
    let dir = tempfile::tempdir().unwrap();
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/default.stcvae");
    let conditions = words("--samples 200000 --tau 2 --g 0 --albedo 1 --seed 7");
    ok(&stcvae(
        &[&["generate"][..], &conditions, &["--out", "g.csv"]].concat(),
        dir.path(),
    ));
    ok(&stcvae(
        &[
            &["sample", "--model", model][..],
            &conditions,
            &["--out", "s.csv"],
        ]
        .concat(),
        dir.path(),
    ));
    let columns = |name: &str| -> Vec<Vec<f64>> {
        let text = fs::read_to_string(dir.path().join(name)).unwrap();
        let mut cols = vec![Vec::new(); 13];
        for line in text.lines().skip(1) {
            for (c, v) in line.split(',').enumerate() {
                cols[c].push(v.parse::<f64>().unwrap());
            }
        }
        cols
    };
    let (g, s) = (columns("g.csv"), columns("s.csv"));
    let n = g[0].len();
    assert_eq!((n, s[0].len()), (200_000, 200_000));
    let mean = |x: &[f64]| x.iter().sum::<f64>() / n as f64;
    let var = |x: &[f64], m: f64| x.iter().map(|v| (v - m).powi(2)).sum::<f64>();
    let mut tested = 0;
    for c in 3..13 {
        let (a, b) = (&g[c], &s[c]);
        let (ma, mb) = (mean(a), mean(b));
        let (va, vb) = (var(a, ma), var(b, mb));
        if va == 0.0 || vb == 0.0 {
            continue;
        }
        let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let z = cov / (va * vb).sqrt() * (n as f64).sqrt();
        assert!(
            z.abs() < 5.0,
            "column {c}: paired-row correlation z = {z:.1}"
        );
        tested += 1;
    }
    assert!(tested >= 8, "only {tested} columns vary");
}

/// Outputs get an ordinary file's mode narrowed by the umask, like any other program's: a
/// fixed 0644 made them readable by everyone under umask 077. Run through `sh` so that
/// the umask is the child's alone (the tests share one process).
#[cfg(unix)]
#[test]
fn outputs_follow_the_umask() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    for (umask, mode) in [("077", 0o600), ("022", 0o644)] {
        let out = std::process::Command::new("sh")
            .arg("-c")
            .arg(format!(
                "umask {umask} && exec \"$0\" generate --samples 10 --tau 1 --g 0 --albedo 1 \
                 --out w{umask}.bin"
            ))
            .arg(env!("CARGO_BIN_EXE_stcvae"))
            .current_dir(dir.path())
            .output()
            .unwrap();
        ok(&out);
        let m = fs::metadata(dir.path().join(format!("w{umask}.bin"))).unwrap();
        assert_eq!(m.permissions().mode() & 0o777, mode, "umask {umask}");
    }
}

/// The last shard of a run of u64::MAX walks holds one walk, the one at index u64::MAX − 1:
/// its chunk's end must not wrap (start + 4,096 did, and the run never ended, filling the
/// disk). The shard's walk index is the run's, so this is a run of one walk.
#[test]
fn the_last_shard_of_the_largest_run_ends() {
    let dir = tempfile::tempdir().unwrap();
    let max = u64::MAX.to_string();
    let shard = format!("{}/{max}", u64::MAX - 1);
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args([
            "generate",
            "--tau",
            "1",
            "--g",
            "0",
            "--albedo",
            "1",
            "--samples",
            &max,
            "--shard",
            &shard,
            "--out",
            "last.csv",
        ])
        .current_dir(dir.path())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // A regression would write walks until the disk is full: stopped and failed once the
    // folder holds over a megabyte (one walk's row is ~100 bytes), whatever the time.
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        let bytes: u64 = fs::read_dir(dir.path())
            .unwrap()
            .flatten()
            .filter_map(|e| e.metadata().ok())
            .map(|m| m.len())
            .sum();
        if bytes > 1 << 20 {
            child.kill().unwrap();
            panic!("the last shard wrote {bytes} bytes and went on");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    assert!(status.success(), "{status}");
    let text = fs::read_to_string(dir.path().join("last.csv")).unwrap();
    assert_eq!(text.lines().count(), 2, "a header and one walk: {text}");
}

/// A run whose file cannot fit on its disk is refused before any walk, naming the file,
/// the least it needs and the space free: `--samples 18446744073709551615` started and
/// showed an ETA of 45,962,785 years. 2^64 − 1 walks of 56 bytes exceed any file system.
/// (Unix: elsewhere the free space is not read, and the run would start.)
#[cfg(unix)]
#[test]
fn a_run_larger_than_its_disk_is_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    // A file system that reports no sizes (tmpfs with size=0, FUSE without statfs) has no
    // known free space, and the run would start: nothing to check there.
    let c = std::ffi::CString::new(dir.path().as_os_str().as_encoded_bytes()).unwrap();
    let mut st = std::mem::MaybeUninit::<libc::statvfs>::uninit();
    // SAFETY: `c` is a NUL-terminated path and `st` a buffer statvfs fills on success.
    let known = unsafe { libc::statvfs(c.as_ptr(), st.as_mut_ptr()) } == 0
        // SAFETY: statvfs returned 0, so it filled `st`.
        && unsafe { st.assume_init() }.f_blocks > 0;
    if !known {
        common::skip(&format!(
            "a_run_larger_than_its_disk_is_refused_at_once: {} reports no sizes",
            dir.path().display()
        ));
        return;
    }
    // The least a row takes in each format (`least_row_bytes`).
    let max = u64::MAX.to_string();
    for (name, per_walk) in [("x.bin", 56), ("x.csv", 26)] {
        let out = stcvae(&["generate", "--samples", &max, "--out", name], dir.path());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{err}");
        assert!(
            err.contains(&format!(
                "{name}: 18446744073709551615 walks need at least 16.00 EiB ({per_walk} bytes \
                 a walk at least)"
            )) && err.contains("free: lower --samples")
                && err.trim().lines().count() == 1,
            "{err}"
        );
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    }
    // A count the dataset config sets is lowered there: `train`, which generates from its
    // dataset_config, has no --samples (its refusal said "lower --samples").
    fs::write(
        dir.path().join("huge.toml"),
        format!(
            "walks = {max}\nseed = 1\n[conditions]\n\
             tau = {{ kind = \"power\", max = 30.0, exponent = 3.0 }}\n\
             g = {{ kind = \"uniform\", min = -1.0, max = 1.0 }}\n\
             albedo = {{ kind = \"one-minus-power\", epsilon = 1e-6, exponent = 6.0 }}\n"
        ),
    )
    .unwrap();
    let model = "latent = 2\nhidden = [4]\nencoder_hidden = [8]\nsteps = 30\n\
                 batch_size = 64\nlr = 3e-3\nlr_final = 3e-4\nwarmup = 5\n";
    fs::write(
        dir.path().join("t.toml"),
        format!(
            "dataset = \"d.bin\"\ndataset_config = \"huge.toml\"\nout = \"m.stcvae\"\n\
             checkpoint_dir = \"ck\"\n[lengthgen]\n{model}[pathgen]\n{model}[eventgen]\n{model}"
        ),
    )
    .unwrap();
    for args in [
        "generate --config huge.toml --out d.bin",
        "train --config t.toml",
    ] {
        let out = stcvae(&words(args), dir.path());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success()
                && err.contains("d.bin: 18446744073709551615 walks need at least")
                && err.contains("free: lower walks in huge.toml, or write elsewhere"),
            "{args}: {err}"
        );
        assert!(!dir.path().join("d.bin").exists(), "{args}");
    }
    fs::remove_file(dir.path().join("huge.toml")).unwrap();
    fs::remove_file(dir.path().join("t.toml")).unwrap();
    // `sample` too (it wrote 50 MB/s toward a full disk), before it loads the model.
    let out = stcvae(
        &[
            &words("sample --tau 5 --g 0 --albedo 1 --out s.csv --samples")[..],
            &[max.as_str()],
        ]
        .concat(),
        dir.path(),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && err.contains("s.csv: 18446744073709551615 walks need at least 16.00 EiB (26 bytes")
            && err.contains("lower --samples, or write elsewhere")
            && err.trim().lines().count() == 1,
        "{err}"
    );
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
}

/// `merge` holds one input open at a time: under a descriptor limit of 20 it merges 40
/// shards (it opened them all at once and ran out of descriptors at 1,100 shards under
/// the usual 1,024), and the rows are the unsharded run's.
#[cfg(unix)]
#[test]
fn merge_keeps_one_input_open() {
    let dir = tempfile::tempdir().unwrap();
    let gen_args = |extra: &[&str]| {
        let mut v = vec![
            "generate",
            "--samples",
            "400",
            "--tau",
            "2",
            "--g",
            "0",
            "--albedo",
            "1",
        ];
        v.extend_from_slice(extra);
        v.iter().map(|s| s.to_string()).collect::<Vec<_>>()
    };
    let run = |args: Vec<String>| {
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        ok(&stcvae(&a, dir.path()));
    };
    run(gen_args(&["--out", "whole.bin"]));
    let mut names = Vec::new();
    for i in 0..40 {
        let (shard, name) = (format!("{i}/40"), format!("p{i:02}.bin"));
        run(gen_args(&["--shard", &shard, "--out", &name]));
        names.push(name);
    }
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -n 20 && exec \"$0\" merge {} --out merged.bin",
            names.join(" ")
        ))
        .arg(env!("CARGO_BIN_EXE_stcvae"))
        .current_dir(dir.path())
        .output()
        .unwrap();
    ok(&out);
    let (_, whole) = read_dataset(&dir.path().join("whole.bin")).unwrap();
    let (_, merged) = read_dataset(&dir.path().join("merged.bin")).unwrap();
    assert!(whole == merged, "merged rows differ from the unsharded run");
}

/// A shard whose rows no longer match its checksum (one bit of its last row's τ flipped:
/// 5 → 5.0000005, still a valid row) is refused by `merge`, naming it, and no output is
/// left: the check runs as the rows are copied, at the read past each input's last row,
/// and the output would otherwise carry a fresh checksum over the corrupt row.
#[test]
fn merge_refuses_an_input_whose_rows_fail_its_checksum() {
    let dir = tempfile::tempdir().unwrap();
    ok(&stcvae(
        &words("generate --samples 50 --tau 5 --g 0 --albedo 1 --out a.bin"),
        dir.path(),
    ));
    let mut bytes = fs::read(dir.path().join("a.bin")).unwrap();
    // The rows end 12 bytes before the file does (CRC and end marker); a row is 56 bytes,
    // τ its first f32.
    let tau = bytes.len() - 12 - scatter_sim::dataset::ROW_BYTES;
    assert_eq!(
        f32::from_le_bytes(bytes[tau..tau + 4].try_into().unwrap()),
        5.0
    );
    bytes[tau] ^= 1;
    fs::write(dir.path().join("bad.bin"), &bytes).unwrap();
    let out = stcvae(&words("merge bad.bin --out m.bin"), dir.path());
    assert!(!out.status.success());
    let e = stderr(&out);
    assert!(e.contains("bad.bin: checksum mismatch"), "{e}");
    assert!(!dir.path().join("m.bin").exists());
}

/// Fixed conditions without --samples simulate the 10,000 walks `--help` promises.
#[test]
fn fixed_conditions_default_to_ten_thousand_walks() {
    let dir = tempfile::tempdir().unwrap();
    ok(&stcvae(
        &words("generate --tau 1 --g 0 --albedo 1 --out x.bin"),
        dir.path(),
    ));
    let (header, rows) = read_dataset(&dir.path().join("x.bin")).unwrap();
    assert_eq!((header.count, rows.len()), (10_000, 10_000));
}

#[test]
fn shards_merge_into_the_unsharded_run() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = "walks = 3001\nseed = 5\n[conditions]\ntau = { kind = \"power\", max = 30.0, exponent = 3.0 }\n\
               g = { kind = \"uniform\", min = -1.0, max = 1.0 }\n\
               albedo = { kind = \"one-minus-power\", epsilon = 1e-6, exponent = 6.0 }\n";
    fs::write(dir.path().join("small.toml"), cfg).unwrap();
    ok(&stcvae(
        &[
            "generate",
            "--config",
            "small.toml",
            "--out",
            "whole.bin",
            "--threads",
            "1",
        ],
        dir.path(),
    ));
    for i in 0..4 {
        let shard = format!("{i}/4");
        let name = format!("part-{i}.bin");
        ok(&stcvae(
            &[
                "generate",
                "--config",
                "small.toml",
                "--shard",
                &shard,
                "--out",
                &name,
            ],
            dir.path(),
        ));
    }
    // Given out of order: merge sorts shards of one run by walk index.
    ok(&stcvae(
        &[
            "merge",
            "part-2.bin",
            "part-0.bin",
            "part-3.bin",
            "part-1.bin",
            "--out",
            "merged.bin",
        ],
        dir.path(),
    ));
    let (_, whole) = read_dataset(&dir.path().join("whole.bin")).unwrap();
    let (header, merged) = read_dataset(&dir.path().join("merged.bin")).unwrap();
    assert_eq!(header.count, 3001);
    assert!(whole == merged, "merged rows differ from the unsharded run");
    // An input that is itself a merge of shards 0 and 2 holds two pieces with shard 1's
    // walks between them: the merge puts shard 1's rows between its pieces (sorting the
    // inputs by their first piece gave the rows of 0, 2, 1, 3).
    ok(&stcvae(
        &["merge", "part-2.bin", "part-0.bin", "--out", "m02.bin"],
        dir.path(),
    ));
    ok(&stcvae(
        &[
            "merge",
            "part-3.bin",
            "m02.bin",
            "part-1.bin",
            "--out",
            "m0123.bin",
        ],
        dir.path(),
    ));
    let (header, rows) = read_dataset(&dir.path().join("m0123.bin")).unwrap();
    assert_eq!((header.count, header.pieces.len()), (3001, 1));
    assert!(
        whole == rows,
        "a merge of merged shards differs from the unsharded run"
    );
    // A file holding shard 2 before shard 0 (written here directly; merge itself sorts the
    // pieces it writes) is read piece by piece out of its order, shard 0 by a second
    // reader: the rows still come out in walk order.
    let (h2, r2) = read_dataset(&dir.path().join("part-2.bin")).unwrap();
    let (h0, r0) = read_dataset(&dir.path().join("part-0.bin")).unwrap();
    let pieces = [h2.pieces, h0.pieces].concat();
    let mut sink = scatter_sim::dataset::create_sink(
        &dir.path().join("m20.bin"),
        scatter_sim::dataset::Header::new(pieces),
    )
    .unwrap();
    for row in r2.iter().chain(&r0) {
        sink.push(row).unwrap();
    }
    sink.finish().unwrap();
    ok(&stcvae(
        &[
            "merge",
            "m20.bin",
            "part-1.bin",
            "part-3.bin",
            "--out",
            "m20_13.bin",
        ],
        dir.path(),
    ));
    let (_, rows) = read_dataset(&dir.path().join("m20_13.bin")).unwrap();
    assert!(
        whole == rows,
        "pieces out of their file's order kept that order"
    );
    // More shards than walks: an empty shard, said so.
    let out = stcvae(
        &[
            "generate",
            "--samples",
            "3",
            "--shard",
            "1/8",
            "--tau",
            "1",
            "--g",
            "0",
            "--albedo",
            "1",
            "--out",
            "empty.bin",
        ],
        dir.path(),
    );
    ok(&out);
    assert!(
        stderr(&out).contains("warning: shard 1/8 of a run of 3 walks holds no walk"),
        "{}",
        stderr(&out)
    );
    assert_eq!(
        read_dataset(&dir.path().join("empty.bin")).unwrap().0.count,
        0
    );
    // Merged alone (binary, then as a header-only CSV), it makes an empty dataset, said
    // as the shard's emptiness was (written without a word before).
    for (input, out) in [
        ("empty.bin", "empty2.bin"),
        ("empty.bin", "empty.csv"),
        ("empty.csv", "empty2.csv"),
    ] {
        let o = stcvae(&["merge", input, "--out", out], dir.path());
        ok(&o);
        assert!(
            stderr(&o).contains(&format!(
                "warning: the inputs hold no row: {out} is an empty dataset"
            )),
            "{}",
            stderr(&o)
        );
    }
    assert_eq!(
        fs::read_to_string(dir.path().join("empty2.csv"))
            .unwrap()
            .lines()
            .count(),
        1
    );
    // Shard 1 as another simulator drew it (its fingerprint changed; the rows are this
    // build's, which does not matter here): the merge is one run, but warns of the two.
    let fp = scatter_sim::dataset::simulator_fingerprint();
    common::rewrite_dataset(
        &dir.path().join("part-1.bin"),
        &dir.path().join("old-1.bin"),
        |h| {
            assert_eq!(h.pieces[0].simulator.as_deref(), Some(fp));
            h.pieces[0].simulator = Some("0badc0de".into());
        },
    );
    let out = stcvae(
        &["merge", "part-0.bin", "old-1.bin", "--out", "builds.bin"],
        dir.path(),
    );
    ok(&out);
    assert!(
        stderr(&out).contains(&format!(
            "warning: the inputs were drawn by 2 simulators (0badc0de, {fp}; this build's is {fp})"
        )) || stderr(&out).contains(&format!(
            "warning: the inputs were drawn by 2 simulators ({fp}, 0badc0de; this build's is {fp})"
        )),
        "{}",
        stderr(&out)
    );
    let (h, _) = read_dataset(&dir.path().join("builds.bin")).unwrap();
    assert_eq!(h.pieces.len(), 2, "pieces of two simulators are kept apart");
    // A merge missing shards (a cluster job that failed) names the walks it lacks.
    let out = stcvae(
        &["merge", "part-2.bin", "part-0.bin", "--out", "p02.bin"],
        dir.path(),
    );
    ok(&out);
    let piece = |i: usize| {
        let (h, _) = read_dataset(&dir.path().join(format!("part-{i}.bin"))).unwrap();
        (
            h.pieces[0].first_walk,
            h.pieces[0].first_walk + h.pieces[0].count,
        )
    };
    let ((_, a), (b, c), (d, _)) = (piece(0), piece(1), piece(3));
    assert!(a == b && d > c, "shards 1 and 3 follow 0 and 2");
    let want = format!(
        "warning: the inputs hold {} of the run's 3001 walks; missing: walks {b}..{c}, {d}..3001",
        3001 - (c - b) - (3001 - d)
    );
    assert!(stderr(&out).contains(&want), "{}", stderr(&out));
    // Binary → CSV through merge equals a direct CSV run.
    ok(&stcvae(
        &["merge", "merged.bin", "--out", "merged.csv"],
        dir.path(),
    ));
    ok(&stcvae(
        &["generate", "--config", "small.toml", "--out", "direct.csv"],
        dir.path(),
    ));
    assert_eq!(
        fs::read(dir.path().join("merged.csv")).unwrap(),
        fs::read(dir.path().join("direct.csv")).unwrap()
    );
    // Overlapping inputs would duplicate walks: refused.
    let out = stcvae(
        &["merge", "part-0.bin", "merged.bin", "--out", "dup.bin"],
        dir.path(),
    );
    assert!(
        !out.status.success() && stderr(&out).contains("overlap"),
        "{}",
        stderr(&out)
    );
    assert!(!dir.path().join("dup.bin").exists());
    // Walk i depends on the seed, the conditions and i alone: a smaller run of the same
    // seed and conditions holds the larger one's first walks, and merged with a shard of
    // the larger one it duplicates them (it was merged, as "2 different runs").
    ok(&stcvae(
        &[
            "generate",
            "--config",
            "small.toml",
            "--samples",
            "1000",
            "--out",
            "first1000.bin",
        ],
        dir.path(),
    ));
    let (_, first) = read_dataset(&dir.path().join("first1000.bin")).unwrap();
    assert!(
        first[..] == whole[..1000],
        "walk i depends on the run's size"
    );
    let out = stcvae(
        &["merge", "first1000.bin", "part-1.bin", "--out", "dup.bin"],
        dir.path(),
    );
    assert!(
        !out.status.success()
            && stderr(&out).contains("of seed 5 appear twice (runs of 1000 and 3001 walks"),
        "{}",
        stderr(&out)
    );
    assert!(!dir.path().join("dup.bin").exists());
    // Without shared walks they merge: the rows are the larger run's.
    ok(&stcvae(
        &["merge", "first1000.bin", "part-3.bin", "--out", "apart.bin"],
        dir.path(),
    ));
    let (h3, _) = read_dataset(&dir.path().join("part-3.bin")).unwrap();
    let from = h3.pieces[0].first_walk as usize;
    let (_, apart) = read_dataset(&dir.path().join("apart.bin")).unwrap();
    assert!(apart[..1000] == whole[..1000] && apart[1000..] == whole[from..]);
    // A corrupt header that reads as overlapping (one digit of shard 1's first walk
    // changed, so that it starts 10 walks early) is named as corrupt, not as an overlap.
    let mut bytes = fs::read(dir.path().join("part-1.bin")).unwrap();
    let key = b"\"first_walk\":";
    let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len();
    let digits = at + bytes[at..].iter().position(|b| b.is_ascii_digit()).unwrap();
    let tens = digits
        + bytes[digits..]
            .iter()
            .take_while(|b| b.is_ascii_digit())
            .count()
        - 2;
    assert!(
        bytes[tens] > b'0',
        "shard 1 starts at a walk of at least 10"
    );
    bytes[tens] -= 1;
    fs::write(dir.path().join("part-1x.bin"), bytes).unwrap();
    let out = stcvae(
        &["merge", "part-0.bin", "part-1x.bin", "--out", "x.bin"],
        dir.path(),
    );
    assert!(
        !out.status.success()
            && stderr(&out).contains("part-1x.bin: checksum mismatch")
            && !stderr(&out).contains("overlap"),
        "{}",
        stderr(&out)
    );
    // CSV rows carry no walk number: a shard copied under another name is told by its rows.
    ok(&stcvae(
        &["merge", "part-1.bin", "--out", "p1.csv"],
        dir.path(),
    ));
    fs::copy(dir.path().join("p1.csv"), dir.path().join("copy.csv")).unwrap();
    let out = stcvae(
        &["merge", "p1.csv", "copy.csv", "--out", "dup.csv"],
        dir.path(),
    );
    assert!(
        !out.status.success() && stderr(&out).contains("p1.csv and copy.csv hold the same rows"),
        "{}",
        stderr(&out)
    );
    assert!(!dir.path().join("dup.csv").exists());
    // The same CSV as a spreadsheet saves it (a byte-order mark, CRLF line ends) merges
    // into the same rows (it was refused for an "unexpected header row").
    let text = fs::read_to_string(dir.path().join("p1.csv")).unwrap();
    let excel = format!("\u{feff}{}", text.replace('\n', "\r\n"));
    fs::write(dir.path().join("excel.csv"), excel).unwrap();
    ok(&stcvae(
        &["merge", "excel.csv", "--out", "from_excel.csv"],
        dir.path(),
    ));
    assert_eq!(
        fs::read_to_string(dir.path().join("from_excel.csv")).unwrap(),
        text
    );
    // A blank line among the rows is a row emptied: it was skipped without a word, one
    // walk fewer in the output. Refused, naming its line; blank lines at the end (an
    // editor's) still pass.
    let mut holed: Vec<&str> = text.lines().collect();
    assert!(holed.len() > 5, "too few rows to make a hole");
    holed[3] = "";
    fs::write(dir.path().join("holed.csv"), holed.join("\n") + "\n").unwrap();
    let out = stcvae(
        &["merge", "holed.csv", "--out", "holed_out.csv"],
        dir.path(),
    );
    assert!(
        !out.status.success()
            && stderr(&out).contains("holed.csv: line 4: a blank line among the rows"),
        "{}",
        stderr(&out)
    );
    assert!(!dir.path().join("holed_out.csv").exists());
    fs::write(dir.path().join("trailing.csv"), format!("{text}\n \n")).unwrap();
    ok(&stcvae(
        &["merge", "trailing.csv", "--out", "trailing_out.csv"],
        dir.path(),
    ));
    assert_eq!(
        fs::read_to_string(dir.path().join("trailing_out.csv")).unwrap(),
        text
    );
    // A file cut short mid-number (here its last digit; a review's cut read -0.3272 for
    // -0.32728904, within range) is refused by its missing line end; nothing is written.
    fs::write(dir.path().join("cut.csv"), &text[..text.len() - 2]).unwrap();
    let out = stcvae(&["merge", "cut.csv", "--out", "cut_out.csv"], dir.path());
    assert!(
        !out.status.success() && stderr(&out).contains("cut.csv: the last row has no line end"),
        "{}",
        stderr(&out)
    );
    assert!(!dir.path().join("cut_out.csv").exists());
    // A shard of another run (another seed) merges, with a note naming both runs and how
    // much of each the output holds.
    fs::write(
        dir.path().join("other.toml"),
        cfg.replace("seed = 5", "seed = 6"),
    )
    .unwrap();
    let other = [
        "generate",
        "--config",
        "other.toml",
        "--shard",
        "1/4",
        "--out",
        "other-1.bin",
    ];
    ok(&stcvae(&other, dir.path()));
    let out = stcvae(
        &["merge", "part-0.bin", "other-1.bin", "--out", "mixed.bin"],
        dir.path(),
    );
    ok(&out);
    let (header, _) = read_dataset(&dir.path().join("part-0.bin")).unwrap();
    let (other, _) = read_dataset(&dir.path().join("other-1.bin")).unwrap();
    let want = format!(
        "note: the inputs come from 2 different runs: seed 5 ({} of its 3001 walks), seed 6 ({} of its 3001 walks)",
        header.count, other.count
    );
    assert!(
        stderr(&out).contains(&want) && !stderr(&out).contains("warning"),
        "{}",
        stderr(&out)
    );
    // One seed under two condition samplers: walk i of each draws the same random numbers.
    for (g, name) in [("0.4", "g04.bin"), ("0.5", "g05.bin")] {
        ok(&stcvae(
            &[
                "generate",
                "--samples",
                "300",
                "--tau",
                "5",
                "--g",
                g,
                "--albedo",
                "1",
                "--out",
                name,
            ],
            dir.path(),
        ));
    }
    let out = stcvae(
        &["merge", "g04.bin", "g05.bin", "--out", "paired.bin"],
        dir.path(),
    );
    ok(&out);
    assert!(
        stderr(&out).contains(
            "warning: walks 0..300 of seed 1 appear under two condition samplers, drawn from \
             the same random numbers"
        ),
        "{}",
        stderr(&out)
    );
    // The rows are paired indeed: the walks' event counts agree far more often than two
    // independent walks' would (g 0.4 against 0.5 changes few of the early flights).
    let (_, a) = read_dataset(&dir.path().join("g04.bin")).unwrap();
    let (_, b) = read_dataset(&dir.path().join("g05.bin")).unwrap();
    let same = a.iter().zip(&b).filter(|(x, y)| x.n == y.n).count();
    let shuffled = a
        .iter()
        .zip(b.iter().rev())
        .filter(|(x, y)| x.n == y.n)
        .count();
    assert!(
        same > 2 * shuffled,
        "same n: paired {same}, unpaired {shuffled}"
    );
    // An empty piece of seed 1 under another sampler shares no walk: no warning.
    let out = stcvae(
        &[
            "generate",
            "--samples",
            "3",
            "--shard",
            "1/2",
            "--tau",
            "1",
            "--g",
            "0",
            "--albedo",
            "1",
            "--out",
            "one.bin",
        ],
        dir.path(),
    );
    ok(&out);
    let (mut h, _) = read_dataset(&dir.path().join("one.bin")).unwrap();
    h.pieces[0].count = 0;
    assert!(h.pieces[0].first_walk > 0, "{:?}", h.pieces[0]);
    let none = scatter_sim::dataset::Header::new(h.pieces.clone());
    common::write_dataset(&dir.path().join("none.bin"), none, &[]);
    let out = stcvae(
        &["merge", "none.bin", "g04.bin", "--out", "with_none.bin"],
        dir.path(),
    );
    ok(&out);
    assert!(!stderr(&out).contains("warning"), "{}", stderr(&out));
    // A file that does not record its simulator (format 1 or 2) beside one that does: a
    // note, not "2 simulators".
    common::rewrite_dataset(
        &dir.path().join("g05.bin"),
        &dir.path().join("old.bin"),
        |h| h.pieces[0].simulator = None,
    );
    let out = stcvae(
        &["merge", "old.bin", "g04.bin", "--out", "mixed2.bin"],
        dir.path(),
    );
    ok(&out);
    assert!(
        stderr(&out).contains(&format!(
            "note: some inputs (format 1 or 2) do not record their simulator; the others' is {}",
            scatter_sim::dataset::simulator_fingerprint()
        )) && !stderr(&out).contains("simulators ("),
        "{}",
        stderr(&out)
    );
}

#[test]
fn bad_input_gives_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cases: &[(&str, &str)] = &[
        ("generate --tau 5 --g 1.2 --albedo 1 --out x.csv", "g = 1.2"),
        ("generate --tau -1 --g 0 --albedo 1 --out x.csv", "tau"),
        ("generate --tau 5 --g 0 --albedo 1.5 --out x.csv", "albedo"),
        ("generate --config missing.toml --out x.bin", "missing.toml"),
        ("generate --config typo.toml --out x.bin", "walkz"),
        ("generate --config range.toml --out x.bin", "tau.max"),
        ("generate --samples 10 --shard 4/4 --out x.bin", "shard"),
        // The default output is the training set: fixed conditions or a shard replaced it.
        (
            "generate --tau 5 --g 0 --albedo 1",
            "--out is needed in fixed-condition mode (--tau/--g/--albedo): the default, data/train.bin, is the training set",
        ),
        (
            "generate --samples 10 --shard 0/2",
            "--out is needed with --shard",
        ),
        // A negative index meets the shard parser, not "unexpected argument '-1'".
        (
            "generate --samples 10 --shard -1/3 --out x.bin",
            "shard '-1/3': expected i/n",
        ),
        ("merge garbage.bin --out y.bin", "garbage.bin"),
        (
            "generate --config zero.toml --out x.bin",
            "zero.toml: walks = 0 is out of range: allowed [1, 2^64)",
        ),
        ("generate --samples 0 --out x.bin", "--samples"),
        // Datasets merged over a render's file would replace the image.
        (
            "merge whole.csv --out render.exr",
            "--out render.exr: this writes a dataset, as its inputs are (.csv for text, any \
             other name binary, e.g. .bin), not a .exr file",
        ),
        // ... and over a config; `generate` likewise over a model or a config.
        ("merge whole.csv --out data.toml", "not a .toml file"),
        // `-` is not standard output: a file named `-` was written in the working folder.
        (
            "merge whole.csv --out -",
            "--out -: stcvae writes files, not standard output",
        ),
        (
            "sample --tau 5 --g 0 --albedo 1 --samples 10 --out -",
            "--out -: stcvae writes files, not standard output",
        ),
        (
            "render --spp 1 --width 8 --height 8 --out -",
            "--out -: stcvae writes files, not standard output",
        ),
        (
            "generate --samples 10 --tau 5 --g 0 --albedo 1 --out -",
            "--out -: stcvae writes files, not standard output",
        ),
        (
            "generate --samples 10 --out models.stcvae",
            "--out models.stcvae: this writes a dataset",
        ),
        ("generate --samples 10 --out ds.TOML", "not a .TOML file"),
        // A CSV cut short mid-row: refused, naming the file and line.
        (
            "merge cut.csv whole.csv --out x.csv",
            "cut.csv: line 2: expected 13",
        ),
        // A row out of its column's range, as a binary row is checked.
        (
            "merge whole.csv edited.csv --out x.csv",
            "edited.csv: line 3: g = 7.5 outside [-0.999, 0.999]",
        ),
        (
            "merge whole.csv nonutf8.csv --out x.csv",
            "nonutf8.csv: line 1",
        ),
        // Thread counts the OS cannot start (14,715 threads and a stack overflow once).
        (
            "generate --samples 10 --tau 5 --g 0 --albedo 1 --threads 100000 --out x.csv",
            "100000 is out of range: allowed [1, 1024]",
        ),
        // Counts and seeds that are not whole numbers name their range too (clap's own
        // parser said "invalid digit found in string").
        (
            "generate --samples 1.5 --tau 5 --g 0 --albedo 1 --out x.csv",
            "'1.5' for '--samples <SAMPLES>': expected a whole number in [1, 2^64)",
        ),
        (
            "eval --samples -1 --out ev",
            "'-1' for '--samples <SAMPLES>': expected a whole number in [2, 4000000]",
        ),
        (
            "sample --tau 5 --g 0 --albedo 1 --seed -3 --out s.csv",
            "'-3' for '--seed <SEED>': expected a whole number in [0, 2^64)",
        ),
        (
            "merge whole.csv --out afile/x.csv",
            "afile exists and is not a directory",
        ),
        // A sampler given as a number: the form it takes, not serde's enum name.
        (
            "generate --config tauf.toml --out x.bin",
            "tauf.toml:3: invalid type: floating point `5.0`, expected a table such as \
             { kind = \"power\", max = 300.0, exponent = 3.0 } (kind: power, uniform or fixed)",
        ),
        // A config and fixed conditions: one or the other (the config's walks and seed
        // were dropped for 10,000 walks at seed 1 had this check been lost).
        (
            "generate --config ok.toml --tau 5 --g 0 --albedo 1 --out x.bin",
            "--config and --tau/--g/--albedo are exclusive",
        ),
        // An output that is the command's own input: the config would be replaced.
        (
            "generate --config ok.toml --out ok.toml",
            "--out ok.toml is also --config, which the output would replace",
        ),
        // An output below a file: refused before the walks, naming the culprit.
        (
            "generate --samples 10 --tau 5 --g 0 --albedo 1 --out afile/x.bin",
            "afile exists and is not a directory",
        ),
    ];
    ok(&stcvae(
        &words("generate --samples 10 --tau 5 --g 0 --albedo 1 --out whole.csv"),
        dir.path(),
    ));
    let whole = fs::read_to_string(dir.path().join("whole.csv")).unwrap();
    fs::write(
        dir.path().join("cut.csv"),
        &whole[..whole.find('\n').unwrap() + 30],
    )
    .unwrap();
    // Row 2 (line 3) with g = 7.5: every field a finite number, the row impossible.
    let mut lines: Vec<String> = whole.lines().map(str::to_string).collect();
    let mut fields: Vec<&str> = lines[2].split(',').collect();
    fields[1] = "7.5";
    lines[2] = fields.join(",");
    fs::write(dir.path().join("edited.csv"), lines.join("\n")).unwrap();
    let mut bytes = whole.as_bytes().to_vec();
    bytes[0] = 0xff;
    fs::write(dir.path().join("nonutf8.csv"), bytes).unwrap();
    fs::write(dir.path().join("afile"), b"").unwrap();
    fs::write(dir.path().join("typo.toml"), "walkz = 10\n").unwrap();
    fs::write(dir.path().join("zero.toml"), "walks = 0\n").unwrap();
    fs::write(dir.path().join("ok.toml"), "walks = 10\n").unwrap();
    fs::write(
        dir.path().join("tauf.toml"),
        "walks = 10\n[conditions]\ntau = 5.0\n",
    )
    .unwrap();
    fs::write(
        dir.path().join("range.toml"),
        "walks = 10\n[conditions]\ntau = { kind = \"power\", max = 5000.0, exponent = 3.0 }\n\
         g = { kind = \"fixed\", value = 0.0 }\nalbedo = { kind = \"fixed\", value = 1.0 }\n",
    )
    .unwrap();
    fs::write(dir.path().join("garbage.bin"), b"not a dataset").unwrap();
    for &(line, needle) in cases {
        let args = words(line);
        let out = stcvae(&args, dir.path());
        let err = stderr(&out);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(
            err.contains(needle),
            "{args:?}: error does not mention {needle}: {err}"
        );
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
        assert!(!dir.path().join("x.bin").exists() && !dir.path().join("x.csv").exists());
        assert!(!dir.path().join("render.exr").exists());
    }
    assert_eq!(
        fs::read_to_string(dir.path().join("ok.toml")).unwrap(),
        "walks = 10\n"
    );
}

/// `stcvae ARGS` started in `dir`, its stderr captured.
#[cfg(unix)]
fn spawn_in(dir: &std::path::Path, args: &[&str]) -> std::process::Child {
    std::process::Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args(args)
        .current_dir(dir)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap()
}

/// Whether a command's hidden temporary output exists in `dir` (it is writing).
#[cfg(unix)]
fn writing_in(dir: &std::path::Path) -> bool {
    fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .any(|e| e.file_name().to_string_lossy().ends_with(".partial"))
}

/// Ctrl-C (SIGINT) stops `generate` and `sample` after their current chunk: exit status
/// 130, a one-line message, and no file left behind, neither the output nor its hidden
/// temporary (`sample` used to be killed outright and leave a `.partial` of any size).
#[cfg(unix)]
#[test]
fn interrupted_runs_leave_no_files() {
    use common::interrupt_when;
    use std::time::Duration;
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/default.stcvae");
    // The model path is the one argument that could hold a space: kept whole.
    // Runs of a minute and more, stopped within a second, whose files would still fit the
    // disk: both commands refuse, before any work, a file larger than the free space
    // (10¹¹ CSV walks need at least 2.6 TB, and the refusal left this test waiting).
    let sample_tail = words("--tau 5 --g 0.4 --albedo 0.9 --samples 100000000 --out big.csv");
    let runs: [Vec<&str>; 2] = [
        // Into folders that do not exist yet: they are removed again.
        words("generate --samples 100000000 --tau 5 --g 0 --albedo 1 --out new/sub/big.bin"),
        [&["sample", "--model", model][..], &sample_tail].concat(),
    ];
    // The generate run once more with the signal sent twice back to back, as `timeout`
    // does (to the process and its group): the same request, not "Ctrl-C again" (which
    // aborted without the clean stop's message). Both signals leave the test
    // microseconds apart (common::interrupt_when), far inside the 300 ms that make one request, however loaded
    // the machine (two `kill` processes could be more than 300 ms apart there).
    let runs = [(&runs[0], false), (&runs[1], false), (&runs[0], true)];
    for (args, twice) in runs {
        let dir = tempfile::tempdir().unwrap();
        let child = spawn_in(dir.path(), args);
        // Interrupted once its temporary output exists, i.e. mid-work (not at the output
        // check's short-lived probe file).
        let started = || writing_in(dir.path()) || writing_in(&dir.path().join("new/sub"));
        interrupt_when(
            &child,
            started,
            Duration::from_millis(300),
            if twice { 2 } else { 1 },
            &format!("{args:?}"),
        );
        let out = child.wait_with_output().unwrap();
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(130), "{args:?}: {err}");
        assert!(
            err.contains("interrupted: nothing written"),
            "{args:?}: {err}"
        );
        let left: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
        assert!(left.is_empty(), "{args:?} left {left:?}");
    }
}

/// Every file `eval` will write is checked before it starts: a directory where a plot
/// goes failed only after the whole grid (hours at 4M samples).
#[test]
fn eval_checks_its_plot_files_before_it_starts() {
    let dir = tempfile::tempdir().unwrap();
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/default.stcvae");
    fs::create_dir_all(dir.path().join("ev/fig12_cos_beta.png")).unwrap();
    let out = stcvae(
        &["eval", "--model", model, "--samples", "2", "--out", "ev"],
        dir.path(),
    );
    let err = stderr(&out);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("--out ev: ev/fig12_cos_beta.png") && !err.contains("evaluating"),
        "{err}"
    );
}

/// `eval` names as left over only files it writes itself: run in a folder that holds the
/// user's own files (`--out .`), it told them to delete a config and a CSV.
#[test]
fn eval_names_only_its_own_files_as_left_over() {
    let dir = tempfile::tempdir().unwrap();
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/default.stcvae");
    fs::write(dir.path().join("small.toml"), "x = 1\n").unwrap();
    fs::write(dir.path().join("walks.csv"), "tau\n").unwrap();
    // Named like eval's files but not among them: the user's.
    fs::write(dir.path().join("metrics.csv"), "a\n").unwrap();
    fs::write(dir.path().join("fig1.png"), b"png").unwrap();
    // A plot of an earlier grid run, which `--at` does not draw.
    fs::write(dir.path().join("fig11_n.png"), b"png").unwrap();
    let out = stcvae(
        &[
            "eval",
            "--model",
            model,
            "--at",
            "5,0,1",
            "--samples",
            "100",
            "--out",
            ".",
        ],
        dir.path(),
    );
    ok(&out);
    let err = String::from_utf8_lossy(&out.stderr);
    let note = err
        .lines()
        .find(|l| l.contains("of an earlier run"))
        .unwrap_or_else(|| panic!("no note: {err}"));
    assert!(
        note.contains("1 file of an earlier run") && note.contains("fig11_n.png"),
        "{note}"
    );
    assert!(
        !note.contains("small.toml")
            && !note.contains("walks.csv")
            && !note.contains("metrics.csv")
            && !note.contains("fig1.png"),
        "{note}"
    );
}

/// Ctrl-C stops `eval` after its current setting: status 130, the message, no results
/// folder (it ended without a word, status 130 from the default handler). The last
/// setting included: `eval --at` with one setting looked for a stop only between settings,
/// so it wrote its metrics and exited 0 after saying it would stop.
#[cfg(unix)]
#[test]
fn an_interrupted_eval_says_so_and_writes_nothing() {
    use std::io::BufRead;
    use std::time::Duration;
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/default.stcvae");
    for args in [
        "--samples 200000 --out ev",
        "--at 125,0.9,1 --samples 100000 --out ev",
    ] {
        let dir = tempfile::tempdir().unwrap();
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_stcvae"))
            .args(["eval", "--model", model])
            .args(words(args))
            .current_dir(dir.path())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Its first line comes once Ctrl-C's handler is in; a setting of 100,000 samples
        // or more takes seconds, so the signal lands mid-setting.
        let mut lines = std::io::BufReader::new(child.stderr.take().unwrap()).lines();
        let first = lines.next().unwrap().unwrap();
        assert!(first.starts_with("evaluating "), "{args}: {first}");
        common::interrupt_when(&child, || true, Duration::from_millis(200), 1, "eval");
        let rest: Vec<String> = lines.map_while(Result::ok).collect();
        let status = child.wait().unwrap();
        let err = rest.join("\n");
        assert_eq!(status.code(), Some(130), "{args}: {err}");
        assert!(
            err.contains("interrupted: nothing written to ev"),
            "{args}: {err}"
        );
        assert!(!dir.path().join("ev").exists(), "{args}: {err}");
    }
}

/// Ctrl-C in a shell ends every process of the pipeline: with `stcvae … 2>&1 | tee log`
/// the pipe's reader is gone when stcvae writes its "interrupt" line, and SIGPIPE (or a
/// print's panic) ended it before its clean stop: a 1.5 GB hidden temporary stayed. Here
/// the reader is closed just before the signal: the stop must still be clean (status
/// 130, not a signal's death) and leave nothing.
#[cfg(unix)]
#[test]
fn an_interrupt_with_the_output_pipe_gone_still_cleans_up() {
    use common::interrupt_when;
    use std::time::Duration;
    let dir = tempfile::tempdir().unwrap();
    let args = words("generate --samples 100000000 --tau 5 --g 0 --albedo 1 --out big.bin");
    let mut child = spawn_in(dir.path(), &args);
    // Closed once the work runs (its first line, "generating …", went out while the
    // reader was there); the signal follows at once.
    interrupt_when(
        &child,
        || writing_in(dir.path()),
        Duration::ZERO,
        0,
        "generate",
    );
    drop(child.stderr.take());
    interrupt_when(&child, || true, Duration::ZERO, 1, "generate");
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{status:?}");
    let left: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
    assert!(left.is_empty(), "left {left:?}");
}

/// A closed output pipe is a request to stop, as Ctrl-C is (`stcvae generate … 2>&1 | less`
/// and quitting less): SIGPIPE's default ended the process at its next line, leaving its
/// hidden temporary. Here stderr is a pipe whose reader is closed before the start, so
/// the first line already finds it closed: the run of 10⁸ walks (a minute; 5.6 GB at
/// least, within the free space `generate` asks for) must stop at once, write nothing, and exit with 141 (128 + SIGPIPE), not die of the signal.
#[cfg(unix)]
#[test]
fn a_closed_output_pipe_stops_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args(words(
            "generate --samples 100000000 --tau 5 --g 0 --albedo 1 --out big.bin",
        ))
        .current_dir(dir.path())
        .stderr(writer)
        .status()
        .unwrap();
    assert_eq!(status.code(), Some(141), "{status:?}");
    let left: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
    assert!(left.is_empty(), "left {left:?}");
}

/// A table printed to a full disk is an error (`eval` and the benches print theirs on
/// standard output): the print macros dropped every write error, so `eval … > table.md` on
/// a full disk cut the table short, said nothing and exited 0. /dev/full fails every write
/// with ENOSPC.
#[cfg(target_os = "linux")]
#[test]
fn a_table_printed_to_a_full_disk_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    // (--help and --version too: clap's own writer dropped the error and exited 0.)
    for args in [
        "bench sim --walks 1024 --threads 1",
        "eval --samples 200 --at 5,0.4,1 --out ev",
        "render --help",
        "--version",
    ] {
        let full = fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_stcvae"))
            .args(words(args))
            .current_dir(dir.path())
            .stdout(full)
            .output()
            .unwrap();
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{args}: {err}");
        assert!(
            err.contains(
                "error: cannot write standard output (its text is cut short): No space left \
                 on device"
            ) && err.trim().lines().last().unwrap().starts_with("error: "),
            "{args}: {err}"
        );
    }
}

/// Paths and the environment read as the user means them (a campaign's findings):
/// - an output through a folder not made yet and then `..` (`new/../a.bin`) passed every
///   check, so `merge` replaced its own input and `generate` could reach /dev: refused
///   before the work now, with nothing made;
/// - `--model models/default.stcvae` typed from another folder failed, though it is the
///   default the help shows and the same path left out was found;
/// - an empty path drew "a value is required … but none was supplied";
/// - a RAYON_NUM_THREADS that rayon cannot read used every core without a word.
#[test]
fn paths_and_the_environment_are_read_as_meant() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let walks = |seed: &str, out: &str| {
        stcvae(
            &[
                &words("generate --samples 50 --tau 5 --g 0 --albedo 1 --seed")[..],
                &[seed, "--out", out],
            ]
            .concat(),
            d,
        )
    };
    ok(&walks("1", "a.bin"));
    ok(&walks("2", "b.bin"));
    let a = fs::read(d.join("a.bin")).unwrap();
    let e = stcvae(&words("merge a.bin b.bin --out new/../a.bin"), d);
    assert!(
        !e.status.success() && stderr(&e).contains("--out would overwrite the input a.bin"),
        "{}",
        stderr(&e)
    );
    assert_eq!(
        fs::read(d.join("a.bin")).unwrap(),
        a,
        "the input was replaced"
    );
    let e = walks("3", "new/../c.bin");
    assert!(
        !e.status.success()
            && stderr(&e).contains("goes up (`..`) out of new, which does not exist yet"),
        "{}",
        stderr(&e)
    );
    assert!(!d.join("new").exists() && !d.join("c.bin").exists());
    // Help without a subcommand still goes whole to standard error, status 2 (a mend of
    // the --help change once cut it to one line).
    let e = stcvae(&[], d);
    assert!(
        e.status.code() == Some(2)
            && stderr(&e).contains("Usage:")
            && stderr(&e).contains("Commands:"),
        "{}",
        stderr(&e)
    );
    // The shipped model, typed, from a folder that is not the repository's.
    ok(&stcvae(
        &words(
            "sample --model models/default.stcvae --tau 5 --g 0.4 --albedo 0.9 --samples 20 \
             --seed 1 --out s.csv",
        ),
        d,
    ));
    for (args, says) in [
        (
            &["generate", "--samples", "5", "--out", ""][..],
            "invalid value '' for '--out <OUT>': an empty path names no file",
        ),
        (
            &["sample", "--model", "", "--out", "t.csv"],
            "an empty path names no model file",
        ),
    ] {
        let e = stcvae(args, d);
        assert!(
            e.status.code() == Some(2) && stderr(&e).contains(says),
            "{args:?}: {}",
            stderr(&e)
        );
    }
    let e = std::process::Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args(words(
            "generate --samples 5 --tau 5 --g 0 --albedo 1 --out r.bin",
        ))
        .current_dir(d)
        .env("RAYON_NUM_THREADS", "abc")
        .output()
        .unwrap();
    ok(&e);
    assert!(
        stderr(&e).contains("warning: RAYON_NUM_THREADS=abc is not a whole number"),
        "{}",
        stderr(&e)
    );
}

/// Ctrl-C stops `merge` too, into CSV and binary: it was killed outright and left its
/// hidden temporary (224 MB for a 4-million-walk dataset) beside the output.
#[cfg(unix)]
#[test]
fn an_interrupted_merge_leaves_no_files() {
    use common::interrupt_when;
    use std::time::Duration;
    let dir = tempfile::tempdir().unwrap();
    // 0.3-0.4 s to merge into binary on the development VM (longer into CSV), many times
    // the 20 ms the signal waits after the temporary appears.
    ok(&stcvae(
        &words("generate --samples 4000000 --tau 5 --g 0 --albedo 1 --seed 3 --out big.bin"),
        dir.path(),
    ));
    for out_name in ["merged.csv", "merged.bin"] {
        let child = spawn_in(dir.path(), &["merge", "big.bin", "--out", out_name]);
        let started = || writing_in(dir.path());
        interrupt_when(&child, started, Duration::from_millis(20), 1, out_name);
        let out = child.wait_with_output().unwrap();
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(130), "{out_name}: {err}");
        assert!(
            err.contains("interrupted: nothing written"),
            "{out_name}: {err}"
        );
        let left: Vec<_> = fs::read_dir(dir.path())
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .filter(|n| n != "big.bin")
            .collect();
        assert!(left.is_empty(), "{out_name}: left {left:?}");
    }
}

/// Where stderr is not a terminal (a batch job's log), the progress bar is written as
/// plain lines every STCVAE_LOG_PROGRESS_EVERY seconds; at 0, at every draw. The bar must
/// show in the captured stderr with its count and unit, one bar state per line.
#[test]
fn progress_reaches_a_log_as_plain_lines() {
    let dir = tempfile::tempdir().unwrap();
    // `stcvae ARGS` with STCVAE_LOG_PROGRESS_EVERY = `every` (stderr is a pipe here).
    let logged = |args: &str, every: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_stcvae"))
            .args(words(args))
            .env("STCVAE_LOG_PROGRESS_EVERY", every)
            .current_dir(dir.path())
            .output()
            .unwrap()
    };
    let out = logged(
        "generate --samples 20000 --tau 20 --g 0.4 --albedo 0.99 --seed 7 --out w.csv",
        "0",
    );
    ok(&out);
    let err = stderr(&out);
    let bars: Vec<&str> = err
        .lines()
        .filter(|l| l.contains("/20,000 walks ("))
        .collect();
    assert!(!bars.is_empty(), "no progress line in:\n{err}");
    assert!(
        bars.iter()
            .all(|l| l.starts_with("00:") && !l.contains('\r')),
        "{err}"
    );
    // A value that is no number of seconds is said once (it was ignored without a word).
    let out = logged(
        "generate --samples 2000 --tau 2 --g 0.4 --albedo 0.99 --seed 7 --out v.csv",
        "-1",
    );
    ok(&out);
    assert_eq!(
        stderr(&out)
            .matches("warning: STCVAE_LOG_PROGRESS_EVERY = \"-1\" is not a number")
            .count(),
        1,
        "{}",
        stderr(&out)
    );
    // Set but empty: the default, without a warning.
    let out = logged(
        "generate --samples 2000 --tau 2 --g 0.4 --albedo 0.99 --seed 7 --out u.csv",
        "",
    );
    ok(&out);
    assert!(
        !stderr(&out).contains("STCVAE_LOG_PROGRESS_EVERY"),
        "{}",
        stderr(&out)
    );
}

/// A closed standard output is a request to stop, not a lost table (`eval … | head`):
/// eval ends with 0 and no write error, where a full disk (/dev/full, tested above) is
/// an error.
#[cfg(unix)]
#[test]
fn a_closed_stdout_is_no_write_error() {
    let dir = tempfile::tempdir().unwrap();
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args(words("eval --samples 200 --at 5,0.4,1 --out ev"))
        .current_dir(dir.path())
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(0), "{err}");
    assert!(!err.contains("cannot write standard output"), "{err}");
}

/// Two header-only CSVs (shards that drew no walk) hold no rows alike, so neither is a
/// copy of the other: they merge into an empty dataset.
#[test]
fn header_only_csvs_are_no_duplicates() {
    let dir = tempfile::tempdir().unwrap();
    let head = scatter_sim::dataset::COLUMNS.join(",") + "\n";
    for name in ["e1.csv", "e2.csv"] {
        fs::write(dir.path().join(name), &head).unwrap();
    }
    let out = stcvae(
        &["merge", "e1.csv", "e2.csv", "--out", "e3.csv"],
        dir.path(),
    );
    ok(&out);
    assert!(
        stderr(&out).contains("merged 2 files, 0 rows -> e3.csv"),
        "{}",
        stderr(&out)
    );
    assert_eq!(fs::read_to_string(dir.path().join("e3.csv")).unwrap(), head);
}
