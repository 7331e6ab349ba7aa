//! Datasets of canonical walks: the row layout, the binary and CSV files, and the
//! parallel, deterministic generator.
//!
//! Binary file layout (little endian), format version [`FORMAT_VERSION`]:
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `STCVAEDS` |
//! | 4 | format version (u32) |
//! | 4 | header length H (u32) |
//! | H | header, JSON ([`Header`]: row count, columns, provenance pieces) |
//! | count × 56 | rows ([`Row::encode`]) |
//! | 4 | CRC-32 of the header and row bytes (version 1: of the row bytes only) |
//! | 8 | end marker `STCVEND!` |
//!
//! The size is known from the header, so truncation is detected before any row is read,
//! and the CRC catches corruption once the rows have streamed past. Version 2 added the
//! header to the CRC: a header damaged into other valid JSON (a seed's digit) passed, and
//! `merge` then took one run's walks twice as "two runs". Version 3 added each piece's
//! `simulator` fingerprint ([`simulator_fingerprint`]). Versions 1 and 2 are still read
//! (their pieces' simulator unknown).

mod binary;
mod csv;
mod error;
mod generate;
mod row;

pub use binary::{DatasetReader, DatasetWriter, read_dataset};
pub use csv::CsvWriter;
pub use error::DatasetError;
pub use generate::{
    GenerateSpec, GenerateSummary, Shard, generate, held_out_rows, simulator_fingerprint, walk_row,
};
pub use row::{COLUMNS, ROW_BYTES, Row};

use serde::{Deserialize, Serialize};
use std::path::Path;

use crate::conditions::ConditionSampler;

pub const MAGIC: &[u8; 8] = b"STCVAEDS";
pub const END_MARKER: &[u8; 8] = b"STCVEND!";
pub const FORMAT_VERSION: u32 = 3;
/// The oldest format version still read (its CRC leaves the header out).
pub const OLDEST_FORMAT_VERSION: u32 = 1;

/// Where a run of rows came from: walks `first_walk .. first_walk + count` of the run
/// with this seed, sampler and total size. A generated file has one piece; a merged
/// file lists the pieces it concatenates, in order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Piece {
    pub seed: u64,
    pub sampler: ConditionSampler,
    pub total_walks: u64,
    pub first_walk: u64,
    pub count: u64,
    /// The simulator that drew the walks ([`simulator_fingerprint`]); absent in files of
    /// format versions 1 and 2. Not part of a run's or a stream's identity: it is the
    /// same walk by intent, and where builds differ `merge` and `train` say so.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simulator: Option<String>,
}

impl Piece {
    /// True if both pieces draw their walks from one stream: walk i depends on the seed,
    /// the sampler and i alone (`walk_row`), so runs of different sizes share their rows.
    pub fn same_stream(&self, other: &Piece) -> bool {
        self.seed == other.seed && self.sampler == other.sampler
    }

    /// True if both pieces come from the same run (same seed, sampler and size).
    pub fn same_run(&self, other: &Piece) -> bool {
        self.seed == other.seed
            && self.sampler == other.sampler
            && self.total_walks == other.total_walks
    }
}

/// The JSON header of a binary dataset. Its fields have not changed since version 1 (the
/// pieces gained `simulator` in version 3, optional), so a key this build does not know is
/// damage or another writer's, and refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Header {
    /// Number of rows.
    pub count: u64,
    /// Column names, in row order (the layout is fixed by the version; a reader refuses a
    /// header that names other columns).
    pub columns: Vec<String>,
    pub pieces: Vec<Piece>,
    /// The program that wrote the file.
    pub generator: String,
}

impl Header {
    /// The simulators its pieces record ([`simulator_fingerprint`]), distinct and sorted,
    /// and whether some piece records none (format versions 1 and 2).
    pub fn simulators(&self) -> (Vec<&str>, bool) {
        let mut seen: Vec<&str> = self
            .pieces
            .iter()
            .filter_map(|p| p.simulator.as_deref())
            .collect();
        seen.sort_unstable();
        seen.dedup();
        (seen, self.pieces.iter().any(|p| p.simulator.is_none()))
    }

    pub fn new(pieces: Vec<Piece>) -> Self {
        Self {
            count: pieces.iter().map(|p| p.count).sum(),
            columns: COLUMNS.iter().map(|c| c.to_string()).collect(),
            pieces,
            generator: format!("stcvae {}", env!("CARGO_PKG_VERSION")),
        }
    }
}

/// Where rows go: a binary dataset or a CSV file, chosen by the output extension.
pub trait RowSink: Send {
    fn push(&mut self, row: &Row) -> Result<(), DatasetError>;
    /// Completes the file and moves it under its final name.
    fn finish(self: Box<Self>) -> Result<(), DatasetError>;
}

/// True if `path` names a CSV file (by extension).
pub fn is_csv(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
}

/// The fewest bytes a row can take in the file `path` names: [`ROW_BYTES`] in the binary
/// format; as CSV text 26 (each of the 13 [`COLUMNS`] one character, 12 commas and a
/// newline; measured rows of τ = 0 walks are 36–38 bytes). What a run's file needs at
/// least, before its header.
pub fn least_row_bytes(path: &Path) -> u64 {
    if is_csv(path) {
        2 * COLUMNS.len() as u64
    } else {
        ROW_BYTES as u64
    }
}

/// Opens the sink for `path`: CSV for `.csv`, the binary format otherwise.
pub fn create_sink(path: &Path, header: Header) -> Result<Box<dyn RowSink>, DatasetError> {
    if is_csv(path) {
        Ok(Box::new(CsvWriter::create(path, header.count)?))
    } else {
        Ok(Box::new(DatasetWriter::create(path, header)?))
    }
}
