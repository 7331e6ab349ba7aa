//! Dataset generation is deterministic across thread counts and shardings; files round
//! trip; damaged files are rejected with errors, not panics.

use std::fs;
use std::path::Path;
use std::sync::atomic::AtomicBool;

use scatter_sim::ConditionSampler;
use scatter_sim::dataset::{
    DatasetError, DatasetReader, GenerateSpec, Header, Shard, create_sink, generate, read_dataset,
};

fn spec(total: u64, shard: Shard) -> GenerateSpec {
    // A cheaper cousin of the authors' sampler (τ ≤ 40) keeps the test fast while still
    // mixing short and long walks, which is what stresses the parallel ordering.
    let mut sampler = ConditionSampler::authors();
    sampler.tau = scatter_sim::conditions::TauSampler::Power {
        max: 40.0,
        exponent: 3.0,
    };
    GenerateSpec {
        seed: 77,
        sampler,
        total_walks: total,
        shard,
    }
}

fn write(spec: &GenerateSpec, path: &Path, threads: usize) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let mut sink = create_sink(path, Header::new(vec![spec.piece()])).unwrap();
    pool.install(|| generate(spec, sink.as_mut(), &AtomicBool::new(false), &mut |_| {}))
        .unwrap();
    sink.finish().unwrap();
}

#[test]
fn identical_bytes_for_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let s = spec(10_000, Shard::WHOLE);
    let (a, b, c) = (
        dir.path().join("1.bin"),
        dir.path().join("2.bin"),
        dir.path().join("3.bin"),
    );
    write(&s, &a, 1);
    write(&s, &b, 2);
    write(&s, &c, 3);
    let bytes = fs::read(&a).unwrap();
    assert_eq!(bytes, fs::read(&b).unwrap());
    assert_eq!(bytes, fs::read(&c).unwrap());
    // Same for CSV.
    let (x, y) = (dir.path().join("1.csv"), dir.path().join("2.csv"));
    write(&s, &x, 1);
    write(&s, &y, 2);
    assert_eq!(fs::read(&x).unwrap(), fs::read(&y).unwrap());
}

#[test]
fn shards_concatenate_to_the_whole_run() {
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.bin");
    write(&spec(5_003, Shard::WHOLE), &whole, 2);
    let (_, all) = read_dataset(&whole).unwrap();
    let mut joined = Vec::new();
    for i in 0..3 {
        let p = dir.path().join(format!("s{i}.bin"));
        write(&spec(5_003, Shard { index: i, count: 3 }), &p, 2);
        let (h, rows) = read_dataset(&p).unwrap();
        assert_eq!(h.pieces[0].first_walk, joined.len() as u64);
        joined.extend(rows);
    }
    assert_eq!(joined.len(), 5_003);
    assert!(joined == all, "shard rows differ from the unsharded run");
}

#[test]
fn round_trip_preserves_header_and_rows() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("d.bin");
    let s = spec(1_000, Shard::WHOLE);
    write(&s, &path, 2);
    let (header, rows) = read_dataset(&path).unwrap();
    assert_eq!(header, Header::new(vec![s.piece()]));
    assert_eq!(rows.len(), 1_000);
    // Each row is exactly what walk_row produces for its index.
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(
            *row,
            scatter_sim::dataset::walk_row(s.seed, &s.sampler, i as u64).0
        );
    }
    // Row invariants hold (the reader validated them too).
    assert!(rows.iter().all(|r| r.validate().is_ok()));
}

fn expect_err(path: &Path) -> DatasetError {
    match DatasetReader::open(path).and_then(|r| r.collect::<Result<Vec<_>, _>>()) {
        Ok(_) => panic!("{} was accepted", path.display()),
        Err(e) => e,
    }
}

#[test]
fn damaged_files_are_rejected_with_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.bin");
    write(&spec(500, Shard::WHOLE), &good, 1);
    let bytes = fs::read(&good).unwrap();
    let put = |name: &str, b: &[u8]| {
        let p = dir.path().join(name);
        fs::write(&p, b).unwrap();
        p
    };

    // Truncated anywhere: in the rows, in the header, in the magic.
    for cut in [bytes.len() - 1, bytes.len() - 100, 40, 12, 3, 0] {
        let e = expect_err(&put("cut.bin", &bytes[..cut]));
        let msg = e.to_string();
        assert!(
            matches!(
                e,
                DatasetError::Truncated { .. } | DatasetError::BadMagic { .. }
            ),
            "cut at {cut}: {msg}"
        );
        assert!(msg.contains("cut.bin"), "error names the file: {msg}");
    }
    // One byte past the end marker: the size must equal the header's, not only cover it.
    let mut padded = bytes.clone();
    padded.push(0);
    let e = expect_err(&put("padded.bin", &padded));
    assert!(
        matches!(e, DatasetError::Truncated { expected, found, .. }
            if expected == bytes.len() as u64 && found == expected + 1),
        "{e}"
    );
    // A flipped bit in a row value: caught by the row check or the checksum.
    let mut flipped = bytes.clone();
    let at = bytes.len() - 12 - 56 * 100 + 30;
    flipped[at] ^= 0x04;
    let e = expect_err(&put("flip.bin", &flipped));
    assert!(
        matches!(
            e,
            DatasetError::Checksum { .. } | DatasetError::BadRow { .. }
        ),
        "{e}"
    );
    // Wrong version.
    let mut v4 = bytes.clone();
    v4[8] = 4;
    let e = expect_err(&put("v4.bin", &v4));
    assert!(matches!(e, DatasetError::Version { found: 4, .. }), "{e}");
    assert!(e.to_string().contains("version 4"));
    // The header is under the checksum (version 2): a seed's digit changed into another
    // valid header is refused (it passed, and merge took the file for another run).
    let seed_at = bytes
        .windows(8)
        .position(|w| w == b"\"seed\":7")
        .expect("the header holds the seed");
    let mut reseeded = bytes.clone();
    reseeded[seed_at + 7] = b'8';
    let e = expect_err(&put("reseeded.bin", &reseeded));
    assert!(matches!(e, DatasetError::Checksum { .. }), "{e}");
    // Version 1 files, whose checksum covers the rows alone, are still read.
    let mut v1 = bytes.clone();
    v1[8] = 1;
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let rows = &bytes[16 + json_len..bytes.len() - 12];
    let crc_at = bytes.len() - 12;
    v1[crc_at..crc_at + 4].copy_from_slice(&crc32fast::hash(rows).to_le_bytes());
    let (_, back) = read_dataset(&put("v1.bin", &v1)).unwrap();
    assert_eq!(back.len(), rows.len() / 56);
    // Not a dataset at all.
    let e = expect_err(&put("text.bin", b"tau,g,albedo\n1,2,3\n"));
    assert!(matches!(e, DatasetError::BadMagic { .. }), "{e}");
    // Corrupt JSON header of the right length.
    let mut bad_json = bytes.clone();
    bad_json[16] = b'#';
    let e = expect_err(&put("json.bin", &bad_json));
    assert!(matches!(e, DatasetError::Header { .. }), "{e}");
    // A renamed column in the header: rows are read by position, so a header that names
    // other columns is refused when the file is opened (the checksum is known only at its
    // end).
    let at = bytes
        .windows(6)
        .position(|w| w == b"\"ev_y\"")
        .expect("the header names ev_y");
    let mut renamed = bytes.clone();
    renamed[at + 4] = b'i';
    let e = expect_err(&put("cols.bin", &renamed));
    assert!(
        matches!(e, DatasetError::Header { .. }) && e.to_string().contains("ev_i"),
        "{e}"
    );
}

#[test]
fn cancelled_generation_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("never.bin");
    let s = spec(100_000, Shard::WHOLE);
    let mut sink = create_sink(&path, Header::new(vec![s.piece()])).unwrap();
    let cancel = AtomicBool::new(true);
    assert!(generate(&s, sink.as_mut(), &cancel, &mut |_| {}).is_err());
    drop(sink);
    let left: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
    assert!(left.is_empty(), "files left behind: {left:?}");
}

#[test]
fn shard_parsing_and_ranges() {
    assert_eq!("2/5".parse::<Shard>(), Ok(Shard { index: 2, count: 5 }));
    for bad in ["5/5", "1/0", "x/3", "3", "-1/2"] {
        assert!(bad.parse::<Shard>().is_err(), "{bad}");
    }
    // Ranges tile [0, total) for awkward totals.
    for total in [0u64, 1, 7, 1000, 4_194_304] {
        for n in [1u64, 3, 8] {
            let mut next = 0;
            for i in 0..n {
                let r = Shard { index: i, count: n }.range(total);
                assert_eq!(r.start, next);
                next = r.end;
            }
            assert_eq!(next, total);
        }
    }
}

/// A header beyond what the reader accepts (16 MiB: a merge of ~76,000 empty pieces) is
/// refused when the file is created, before any row is copied, with the file left
/// unwritten; and a file claiming one is refused as such, not as "truncated" with equal
/// sizes.
#[test]
fn a_header_too_large_to_read_back_is_not_written() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("huge.bin");
    let one = spec(1, Shard::WHOLE).piece();
    let pieces = (0..200_000u64)
        .map(|i| scatter_sim::dataset::Piece {
            seed: i,
            ..one.clone()
        })
        .collect();
    let e = create_sink(&path, Header::new(pieces))
        .err()
        .expect("refused");
    assert!(
        e.to_string()
            .contains("beyond the 16777216 a dataset may have"),
        "{e}"
    );
    assert!(!path.exists());
    // A file that claims a header of 2^24 + 1 bytes.
    let mut bytes = b"STCVAEDS".to_vec();
    bytes.extend(2u32.to_le_bytes());
    bytes.extend(((1u32 << 24) + 1).to_le_bytes());
    bytes.resize(1 << 25, b' ');
    let claimed = dir.path().join("claims.bin");
    fs::write(&claimed, &bytes).unwrap();
    let Err(e) = read_dataset(&claimed) else {
        panic!("a header claiming 2^24 + 1 bytes was read")
    };
    assert!(e.to_string().contains("beyond the 16777216 allowed"), "{e}");
    // A header of exactly 2^24 bytes, the largest allowed, is written and read back.
    let mut h = Header::new(vec![scatter_sim::dataset::Piece {
        count: 0,
        ..one.clone()
    }]);
    h.generator.clear();
    let probe = dir.path().join("probe.bin");
    create_sink(&probe, h.clone()).unwrap().finish().unwrap();
    let bare = u32::from_le_bytes(fs::read(&probe).unwrap()[12..16].try_into().unwrap()) as usize;
    // Each 'x' is one byte of JSON.
    h.generator = "x".repeat((1 << 24) - bare);
    let exact = dir.path().join("exact.bin");
    create_sink(&exact, h.clone()).unwrap().finish().unwrap();
    let exact_bytes = fs::read(&exact).unwrap();
    assert_eq!(
        u32::from_le_bytes(exact_bytes[12..16].try_into().unwrap()),
        1 << 24
    );
    let (back, rows) = read_dataset(&exact).unwrap();
    assert!(rows.is_empty() && back == h);
}

/// A header whose checksum is right but whose content no generate run writes: an unknown
/// key, or a piece whose sampler draws τ beyond the simulator's range. Both are refused
/// when the file is opened, by name, instead of being carried into merged files.
#[test]
fn foreign_headers_with_valid_checksums_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.bin");
    write(&spec(50, Shard::WHOLE), &good, 1);
    let bytes = fs::read(&good).unwrap();
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let json = std::str::from_utf8(&bytes[16..16 + json_len]).unwrap();
    let rows = &bytes[16 + json_len..bytes.len() - 12];
    // The file as a foreign writer would make it: header, rows, CRC over both (version 2).
    let rebuilt = |name: &str, json: &str| {
        let mut out = b"STCVAEDS".to_vec();
        out.extend(2u32.to_le_bytes());
        out.extend((json.len() as u32).to_le_bytes());
        out.extend(json.as_bytes());
        out.extend(rows);
        let mut crc = crc32fast::Hasher::new();
        crc.update(json.as_bytes());
        crc.update(rows);
        out.extend(crc.finalize().to_le_bytes());
        out.extend(b"STCVEND!");
        let p = dir.path().join(name);
        fs::write(&p, out).unwrap();
        p
    };
    // The rebuilt original is read: the test's own writer is right.
    let (header, back) = read_dataset(&rebuilt("same.bin", json)).unwrap();
    assert_eq!(back.len(), 50);
    // Each piece records the simulator that drew it (format version 3), 8 hex digits; a
    // header without it (versions 1 and 2) reads as unknown.
    let fp = scatter_sim::dataset::simulator_fingerprint();
    assert!(
        fp.len() == 8 && fp.chars().all(|c| c.is_ascii_hexdigit()),
        "{fp}"
    );
    assert_eq!(header.pieces[0].simulator.as_deref(), Some(fp));
    assert_eq!(bytes[8], 3, "written as format version 3");
    let unrecorded = json.replacen(&format!(",\"simulator\":\"{fp}\""), "", 1);
    assert_ne!(unrecorded, json, "the header holds the fingerprint");
    let (header, _) = read_dataset(&rebuilt("v2.bin", &unrecorded)).unwrap();
    assert_eq!(header.pieces[0].simulator, None);

    let extra = json.replacen("{", "{\"weights\":[1,2],", 1);
    let e = expect_err(&rebuilt("extra.bin", &extra));
    let msg = e.to_string();
    assert!(
        matches!(e, DatasetError::Header { .. }) && msg.contains("weights"),
        "{msg}"
    );
    assert!(msg.contains("extra.bin"), "{msg}");

    // Walks 10..60 of a run of 50, and piece counts that no longer add up: both refused.
    let beyond = json.replacen("\"first_walk\":0", "\"first_walk\":10", 1);
    assert_ne!(beyond, json);
    let at = json.rfind("\"count\":50").expect("the piece's count");
    let short = format!("{}\"count\":49{}", &json[..at], &json[at + 10..]);
    for (name, text, says) in [
        (
            "beyond.bin",
            &beyond,
            "a piece holds walks 10 + 50 of a run of 50: beyond the run's end",
        ),
        (
            "sum.bin",
            &short,
            "piece counts do not add up to the row count",
        ),
    ] {
        let e = expect_err(&rebuilt(name, text));
        assert!(
            matches!(e, DatasetError::Header { .. }) && e.to_string().contains(says),
            "{e}"
        );
    }

    let wide = json.replacen("\"max\":40.0", "\"max\":4000.0", 1);
    assert_ne!(wide, json, "the header holds tau's max as written");
    let e = expect_err(&rebuilt("wide.bin", &wide));
    let msg = e.to_string();
    assert!(
        matches!(e, DatasetError::Header { .. })
            && msg.contains("tau.max")
            && msg.contains("[0, 1000]"),
        "{msg}"
    );
}

/// The held-out walks of a dataset are the walks its run would have drawn next: equal, row
/// for row, to the start of the second half of a run twice as long with the same seed, so
/// none of them is in the dataset and their distribution is the dataset's. Shards of one
/// run count as that run once, runs of one seed and sampler as one stream; two runs share
/// the walks by their row counts.
#[test]
fn held_out_walks_are_the_runs_next_walks() {
    use scatter_sim::dataset::{Piece, held_out_rows, walk_row};
    let dir = tempfile::tempdir().unwrap();
    let whole = spec(300, Shard::WHOLE);
    let longer = dir.path().join("longer.bin");
    let mut second_half = spec(600, Shard { index: 1, count: 2 });
    second_half.seed = whole.seed;
    write(&second_half, &longer, 2);
    let (_, next) = read_dataset(&longer).unwrap();
    let held = held_out_rows(&[whole.piece()], 100);
    assert_eq!(held.len(), 100);
    assert!(
        held == next[..100],
        "the held-out walks are walks 300..400 of the run"
    );

    let shards: Vec<Piece> = (0..3)
        .map(|i| spec(300, Shard { index: i, count: 3 }).piece())
        .collect();
    assert!(
        held_out_rows(&shards, 100) == held,
        "three shards are one run"
    );

    let mut other = spec(100, Shard::WHOLE);
    other.seed = 5;
    let mixed = held_out_rows(&[whole.piece(), other.piece()], 10);
    // 10 walks over 300 + 100 rows: 7.5 and 2.5, the tie's extra walk to the first run.
    let expected: Vec<_> = (0..8)
        .map(|j| walk_row(whole.seed, &whole.sampler, 300 + j).0)
        .chain((0..2).map(|j| walk_row(5, &other.sampler, 100 + j).0))
        .collect();
    assert!(mixed == expected);
    // Runs of one seed and sampler are one stream: a run of 600 beside the run of 300
    // holds the latter's next walks, so the held-out walks start at 600.
    let longer_run = spec(600, Shard::WHOLE).piece();
    let beside = held_out_rows(&[whole.piece(), longer_run], 4);
    let after: Vec<_> = (600..604)
        .map(|j| walk_row(whole.seed, &whole.sampler, j).0)
        .collect();
    assert!(beside == after);
    assert!(held_out_rows(&[], 10).is_empty());
}
