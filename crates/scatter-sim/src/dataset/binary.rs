//! The binary dataset file: streaming writer and validating reader.

use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};

use super::{
    DatasetError, END_MARKER, FORMAT_VERSION, Header, MAGIC, OLDEST_FORMAT_VERSION, ROW_BYTES, Row,
    RowSink,
};
use crate::output::AtomicFile;

/// Bytes before the rows that do not depend on the header: magic, version, header length.
const PREAMBLE: u64 = 16;
/// Bytes after the rows: CRC and end marker.
const TRAILER: u64 = 12;
/// Headers are small JSON; anything larger is corruption, not a header.
const MAX_HEADER: u32 = 1 << 24;

/// Writes rows as they come; the file appears under its name only after `finish`.
pub struct DatasetWriter {
    file: AtomicFile,
    crc: crc32fast::Hasher,
    expected: u64,
    written: u64,
}

impl DatasetWriter {
    pub fn create(path: &Path, header: Header) -> Result<Self, DatasetError> {
        let io = |e| DatasetError::io(path, e);
        let json = serde_json::to_vec(&header).expect("header serialises");
        // What the reader accepts (a merge of 76,000 empty pieces wrote a header of 17.6 MB
        // that no command could read back).
        if json.len() > MAX_HEADER as usize {
            return Err(DatasetError::Other {
                path: path.into(),
                msg: format!(
                    "its header would take {} bytes for {} pieces, beyond the {MAX_HEADER} a \
                     dataset may have: merge the pieces in fewer, larger runs",
                    json.len(),
                    header.pieces.len()
                ),
            });
        }
        let mut file = AtomicFile::create(path).map_err(io)?;
        file.write_all(MAGIC).map_err(io)?;
        file.write_all(&FORMAT_VERSION.to_le_bytes()).map_err(io)?;
        file.write_all(&(json.len() as u32).to_le_bytes())
            .map_err(io)?;
        file.write_all(&json).map_err(io)?;
        let mut crc = crc32fast::Hasher::new();
        crc.update(&json);
        Ok(Self {
            file,
            crc,
            expected: header.count,
            written: 0,
        })
    }
}

impl RowSink for DatasetWriter {
    fn push(&mut self, row: &Row) -> Result<(), DatasetError> {
        let mut buf = [0u8; ROW_BYTES];
        row.encode(&mut buf);
        self.crc.update(&buf);
        self.written += 1;
        self.file
            .write_all(&buf)
            .map_err(|e| DatasetError::io(self.file.path(), e))
    }

    fn finish(mut self: Box<Self>) -> Result<(), DatasetError> {
        let path = self.file.path().to_path_buf();
        if self.written != self.expected {
            return Err(DatasetError::Other {
                path,
                msg: format!(
                    "wrote {} rows but the header promises {}",
                    self.written, self.expected
                ),
            });
        }
        let crc = self.crc.clone().finalize();
        let io = |e| DatasetError::io(&path, e);
        self.file.write_all(&crc.to_le_bytes()).map_err(io)?;
        self.file.write_all(END_MARKER).map_err(io)?;
        self.file.commit().map_err(io)
    }
}

/// Streams the rows of a binary dataset, validating as it goes: size and header up
/// front, each row's invariants as it is read, the checksum after the last row.
pub struct DatasetReader {
    path: PathBuf,
    header: Header,
    reader: BufReader<File>,
    crc: crc32fast::Hasher,
    next_row: u64,
    done: bool,
}

impl DatasetReader {
    pub fn open(path: &Path) -> Result<Self, DatasetError> {
        let io = |e| DatasetError::io(path, e);
        crate::output::check_input(path).map_err(io)?;
        let file = File::open(path).map_err(io)?;
        let size = file.metadata().map_err(io)?.len();
        let mut reader = BufReader::with_capacity(1 << 20, file);
        let too_short = |expected| DatasetError::Truncated {
            path: path.into(),
            expected,
            found: size,
        };
        if size < PREAMBLE {
            return Err(if size >= 8 {
                let mut magic = [0u8; 8];
                reader.read_exact(&mut magic).map_err(io)?;
                if &magic != MAGIC {
                    DatasetError::BadMagic { path: path.into() }
                } else {
                    too_short(PREAMBLE + TRAILER)
                }
            } else {
                DatasetError::BadMagic { path: path.into() }
            });
        }
        let mut pre = [0u8; PREAMBLE as usize];
        reader.read_exact(&mut pre).map_err(io)?;
        if &pre[..8] != MAGIC {
            return Err(DatasetError::BadMagic { path: path.into() });
        }
        let version = u32::from_le_bytes(pre[8..12].try_into().unwrap());
        if !(OLDEST_FORMAT_VERSION..=FORMAT_VERSION).contains(&version) {
            return Err(DatasetError::Version {
                path: path.into(),
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        let header_len = u32::from_le_bytes(pre[12..16].try_into().unwrap());
        if header_len > MAX_HEADER {
            return Err(DatasetError::Header {
                path: path.into(),
                msg: format!("it claims {header_len} bytes, beyond the {MAX_HEADER} allowed"),
            });
        }
        if PREAMBLE + header_len as u64 > size {
            return Err(too_short(PREAMBLE + header_len as u64 + TRAILER));
        }
        let mut json = vec![0u8; header_len as usize];
        reader.read_exact(&mut json).map_err(io)?;
        let header: Header = serde_json::from_slice(&json).map_err(|e| DatasetError::Header {
            path: path.into(),
            msg: e.to_string(),
        })?;
        check_header(&header).map_err(|msg| DatasetError::Header {
            path: path.into(),
            msg,
        })?;
        let expected = header
            .count
            .checked_mul(ROW_BYTES as u64)
            .and_then(|b| b.checked_add(PREAMBLE + header_len as u64 + TRAILER))
            .ok_or_else(|| DatasetError::Header {
                path: path.into(),
                msg: format!("impossible row count {}", header.count),
            })?;
        if expected != size {
            return Err(too_short(expected));
        }
        let mut crc = crc32fast::Hasher::new();
        if version >= 2 {
            crc.update(&json);
        }
        Ok(Self {
            path: path.into(),
            header,
            reader,
            crc,
            next_row: 0,
            done: false,
        })
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// How many rows have been read so far.
    pub fn rows_read(&self) -> u64 {
        self.next_row
    }

    /// The next row, `None` after the last (once the checksum has been verified).
    pub fn next_row(&mut self) -> Result<Option<Row>, DatasetError> {
        if self.done {
            return Ok(None);
        }
        let io = |e| DatasetError::io(&self.path, e);
        if self.next_row == self.header.count {
            let mut trailer = [0u8; TRAILER as usize];
            self.reader.read_exact(&mut trailer).map_err(io)?;
            let stored = u32::from_le_bytes(trailer[..4].try_into().unwrap());
            if &trailer[4..] != END_MARKER || stored != self.crc.clone().finalize() {
                return Err(DatasetError::Checksum {
                    path: self.path.clone(),
                });
            }
            self.done = true;
            return Ok(None);
        }
        let mut buf = [0u8; ROW_BYTES];
        self.reader.read_exact(&mut buf).map_err(io)?;
        self.crc.update(&buf);
        let row = Row::decode(&buf);
        row.validate().map_err(|msg| DatasetError::BadRow {
            path: self.path.clone(),
            row: self.next_row,
            msg,
        })?;
        self.next_row += 1;
        Ok(Some(row))
    }
}

/// The header's columns and numbers, checked when the file is opened: the checksum (over
/// the header too since version 2) is known only after the rows have streamed past.
fn check_header(header: &Header) -> Result<(), String> {
    // The rows are read by position.
    if header
        .columns
        .iter()
        .map(String::as_str)
        .ne(super::COLUMNS.iter().copied())
    {
        return Err(format!(
            "columns [{}] differ from this build's [{}]",
            header.columns.join(", "),
            super::COLUMNS.join(", ")
        ));
    }
    if let Some(p) = header.pieces.iter().find(|p| {
        p.first_walk
            .checked_add(p.count)
            .is_none_or(|end| end > p.total_walks)
    }) {
        return Err(format!(
            "a piece holds walks {} + {} of a run of {}: beyond the run's end",
            p.first_walk, p.count, p.total_walks
        ));
    }
    // A piece's sampler is provenance that merge compares and training reports; one
    // no generate run could have used (hand-edited, or another writer's) is refused
    // by its field and range rather than carried into a merged file.
    for (i, p) in header.pieces.iter().enumerate() {
        if let Err(e) = p.sampler.validate() {
            return Err(format!("piece {i}'s sampler: {e}"));
        }
    }
    // Merge adds and compares counts.
    let sum = header
        .pieces
        .iter()
        .try_fold(0u64, |acc, p| acc.checked_add(p.count));
    if sum != Some(header.count) {
        return Err("piece counts do not add up to the row count".into());
    }
    Ok(())
}

impl Iterator for DatasetReader {
    type Item = Result<Row, DatasetError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.next_row().transpose()
    }
}

/// Reads a whole binary dataset (validated) into memory.
pub fn read_dataset(path: &Path) -> Result<(Header, Vec<Row>), DatasetError> {
    let reader = DatasetReader::open(path)?;
    let header = reader.header().clone();
    let rows = reader.collect::<Result<Vec<_>, _>>()?;
    Ok((header, rows))
}
