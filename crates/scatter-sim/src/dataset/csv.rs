//! CSV output for looking at walks in other tools (spreadsheets, pandas, gnuplot).

use std::io::Write;
use std::path::Path;

use super::{COLUMNS, DatasetError, Row, RowSink};
use crate::output::AtomicFile;

pub struct CsvWriter {
    file: AtomicFile,
    expected: u64,
    written: u64,
}

impl CsvWriter {
    pub fn create(path: &Path, expected_rows: u64) -> Result<Self, DatasetError> {
        let mut file = AtomicFile::create(path).map_err(|e| DatasetError::io(path, e))?;
        writeln!(file, "{}", COLUMNS.join(",")).map_err(|e| DatasetError::io(path, e))?;
        Ok(Self {
            file,
            expected: expected_rows,
            written: 0,
        })
    }
}

impl RowSink for CsvWriter {
    fn push(&mut self, row: &Row) -> Result<(), DatasetError> {
        self.written += 1;
        row.write_csv(&mut self.file)
            .map_err(|e| DatasetError::io(self.file.path(), e))
    }

    fn finish(self: Box<Self>) -> Result<(), DatasetError> {
        let path = self.file.path().to_path_buf();
        if self.written != self.expected {
            return Err(DatasetError::Other {
                path,
                msg: format!("wrote {} rows, expected {}", self.written, self.expected),
            });
        }
        self.file.commit().map_err(|e| DatasetError::io(path, e))
    }
}
