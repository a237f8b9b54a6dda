//! Parquet tables: reading with schema checks, atomic writing with provenance in
//! the file's key-value metadata, and the `parameters` table conversion.
//!
//! Provenance is stored under the key `egcal.provenance` as one JSON object so
//! that `egcal show` (and any Parquet tool) can print where a table came from.

pub mod parameters;
pub mod residual_model;
pub mod schema;
pub mod time;

use std::collections::BTreeMap;
use std::fs::File;
use std::path::Path;

use polars::prelude::*;
use serde::{Deserialize, Serialize};

use schema::io_error;
pub use schema::{TableError, TableSchema};
pub use time::{now_rfc3339, parse_rfc3339_us};

/// The metadata key provenance is stored under.
pub const PROVENANCE_KEY: &str = "egcal.provenance";

/// Where an output table came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Provenance {
    pub job: String,
    pub stage_id: String,
    pub stage_kind: String,
    pub cache_key: String,
    /// Input name → content hash (blake3 hex).
    pub input_hashes: BTreeMap<String, String>,
    pub tool_version: String,
    /// RFC 3339, UTC.
    pub created_at: String,
    /// Stage-specific facts worth keeping with the table (rejection counts, ...).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub extra: BTreeMap<String, String>,
}

/// Reads a whole Parquet file.
pub fn read_parquet(path: &Path) -> Result<DataFrame, TableError> {
    let file = File::open(path).map_err(|e| io_error(path, format!("cannot open: {e}")))?;
    ParquetReader::new(file)
        .finish()
        .map_err(|e| io_error(path, format!("not a readable Parquet file: {e}")))
}

/// Reads a Parquet file and checks it against `schema`.
pub fn read_checked(path: &Path, schema: &TableSchema) -> Result<DataFrame, TableError> {
    let df = read_parquet(path)?;
    schema.check(&df, path)?;
    Ok(df)
}

/// Reads only the footer: column names with types, row count and key-value metadata.
pub struct Footer {
    pub columns: Vec<(String, String)>,
    pub rows: usize,
    pub metadata: BTreeMap<String, String>,
}

pub fn read_footer(path: &Path) -> Result<Footer, TableError> {
    let file = File::open(path).map_err(|e| io_error(path, format!("cannot open: {e}")))?;
    let mut reader = ParquetReader::new(file);
    let bad = |e: PolarsError| io_error(path, format!("not a readable Parquet file: {e}"));
    let schema = reader.schema().map_err(bad)?;
    let columns = schema
        .iter()
        .map(|(name, field)| {
            (
                name.to_string(),
                DataType::from_arrow_dtype(field.dtype()).to_string(),
            )
        })
        .collect();
    let metadata = reader.get_metadata().map_err(bad)?;
    let rows = metadata.num_rows;
    let metadata = metadata
        .key_value_metadata()
        .iter()
        .flatten()
        .filter_map(|kv| kv.value.clone().map(|v| (kv.key.clone(), v)))
        .collect();
    Ok(Footer {
        columns,
        rows,
        metadata,
    })
}

/// Provenance of a table written by egcal, if it has one.
pub fn read_provenance(path: &Path) -> Result<Option<Provenance>, TableError> {
    let footer = read_footer(path)?;
    footer
        .metadata
        .get(PROVENANCE_KEY)
        .map(|json| {
            serde_json::from_str(json).map_err(|e| io_error(path, format!("bad provenance: {e}")))
        })
        .transpose()
}

/// Writes `df` atomically with provenance in the footer.
pub fn write_parquet(
    df: &mut DataFrame,
    path: &Path,
    provenance: Option<&Provenance>,
) -> Result<(), TableError> {
    crate::fsio::write_atomic(path, |file| encode_parquet(df, provenance, file))
        .map_err(|e| io_error(path, format!("cannot write: {e}")))
}

/// Writes `df` with provenance in the footer as a new file in a folder that
/// is renamed into place as a whole ([`crate::fsio::write_unpublished`]: one
/// fsync, no temporary), and returns the blake3 of the bytes written, hashed
/// on the way out rather than read back.
pub fn write_parquet_unpublished(
    df: &mut DataFrame,
    path: &Path,
    provenance: Option<&Provenance>,
) -> Result<String, TableError> {
    let mut hasher = blake3::Hasher::new();
    crate::fsio::write_unpublished(path, |file| {
        encode_parquet(
            df,
            provenance,
            &mut HashingWriter {
                inner: file,
                hasher: &mut hasher,
            },
        )
    })
    .map_err(|e| io_error(path, format!("cannot write: {e}")))?;
    Ok(hasher.finalize().to_hex().to_string())
}

/// `df` as Parquet into `out`, through a buffer: the writer emits each page
/// header and column chunk as its own small write (unbuffered, a 10 000-row
/// table took 2 800 system calls). Snappy, the Parquet readers' common
/// default, rather than polars' zstd: a 10 000-row night's residual table
/// encodes in 3 ms instead of 9, for files 10–25 % larger (issue #31).
fn encode_parquet(
    df: &mut DataFrame,
    provenance: Option<&Provenance>,
    out: &mut impl std::io::Write,
) -> std::io::Result<()> {
    let metadata = provenance.map(|p| {
        KeyValueMetadata::from_static(vec![(
            PROVENANCE_KEY.to_string(),
            serde_json::to_string(p).expect("provenance serialises"),
        )])
    });
    let mut buffered = std::io::BufWriter::with_capacity(1 << 20, out);
    ParquetWriter::new(&mut buffered)
        .with_compression(ParquetCompression::Snappy)
        .with_key_value_metadata(metadata)
        .finish(df)
        .map_err(std::io::Error::other)?;
    std::io::Write::flush(&mut buffered)
}

/// Passes writes through to `inner` and hashes them.
struct HashingWriter<'a, W> {
    inner: W,
    hasher: &'a mut blake3::Hasher,
}

impl<W: std::io::Write> std::io::Write for HashingWriter<'_, W> {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        let written = self.inner.write(bytes)?;
        self.hasher.update(&bytes[..written]);
        Ok(written)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Blake3 of a table's data: column names, types and values, not its metadata.
/// Two runs that produce the same table give the same hash even though their
/// provenance (creation time, cache key) differs; downstream cache keys use this.
pub fn content_hash(df: &DataFrame) -> String {
    let mut hasher = BufferedHasher::default();
    hasher.update(&(df.height() as u64).to_le_bytes());
    for column in df.columns() {
        hasher.update(column.name().as_bytes());
        hasher.update(&[0]);
        hasher.update(column.dtype().to_string().as_bytes());
        hasher.update(&[0]);
        let physical = column.to_physical_repr();
        match physical.dtype() {
            DataType::Float64 => {
                for v in physical.f64().expect("f64 column").iter() {
                    hash_option(&mut hasher, v.map(f64::to_bits));
                }
            }
            DataType::Int64 => {
                for v in physical.i64().expect("i64 column").iter() {
                    hash_option(&mut hasher, v.map(|x| x as u64));
                }
            }
            DataType::Boolean => {
                for v in physical.bool().expect("bool column").iter() {
                    hash_option(&mut hasher, v.map(u64::from));
                }
            }
            _ => {
                let text = physical
                    .cast(&DataType::String)
                    .expect("any column casts to text");
                for v in text.str().expect("str column").iter() {
                    match v {
                        Some(s) => {
                            hasher.update(&[1]);
                            hasher.update(&(s.len() as u64).to_le_bytes());
                            hasher.update(s.as_bytes());
                        }
                        None => {
                            hasher.update(&[0]);
                        }
                    }
                }
            }
        }
    }
    hasher.finalize().to_hex().to_string()
}

/// Blake3 fed in 64 KiB pieces: the hash of a stream does not depend on how
/// it is cut, and an `update` per 8-byte value cost 0.6 s for a
/// million-row table (issue #31).
struct BufferedHasher {
    hasher: blake3::Hasher,
    pending: Vec<u8>,
}

impl Default for BufferedHasher {
    fn default() -> Self {
        BufferedHasher {
            hasher: blake3::Hasher::new(),
            pending: Vec::with_capacity(Self::PIECE_BYTES),
        }
    }
}

impl BufferedHasher {
    const PIECE_BYTES: usize = 64 * 1024;

    fn update(&mut self, bytes: &[u8]) {
        if self.pending.len() + bytes.len() > Self::PIECE_BYTES {
            self.hasher.update(&self.pending);
            self.pending.clear();
        }
        if bytes.len() > Self::PIECE_BYTES {
            self.hasher.update(bytes);
        } else {
            self.pending.extend_from_slice(bytes);
        }
    }

    fn finalize(mut self) -> blake3::Hash {
        self.hasher.update(&self.pending);
        self.hasher.finalize()
    }
}

fn hash_option(hasher: &mut BufferedHasher, value: Option<u64>) {
    match value {
        Some(v) => {
            hasher.update(&[1]);
            hasher.update(&v.to_le_bytes());
        }
        None => {
            hasher.update(&[0]);
        }
    }
}

/// Builds a data frame from named f64/i64/str columns of equal length.
pub fn frame(columns: Vec<Column>) -> DataFrame {
    let height = columns.first().map_or(0, |c| c.len());
    DataFrame::new(height, columns).expect("columns of equal length with unique names")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn provenance_round_trips_through_the_footer() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.parquet");
        let mut df = frame(vec![Column::new("cw_id".into(), vec![1i64, 2, 3])]);
        let provenance = Provenance {
            job: "j".into(),
            stage_id: "s".into(),
            stage_kind: "predict".into(),
            cache_key: "abc".into(),
            input_hashes: [("input".to_string(), "123".to_string())].into(),
            tool_version: "0.1.0".into(),
            created_at: now_rfc3339(),
            extra: BTreeMap::new(),
        };
        write_parquet(&mut df, &path, Some(&provenance)).unwrap();
        assert_eq!(read_provenance(&path).unwrap(), Some(provenance));
        let footer = read_footer(&path).unwrap();
        assert_eq!(footer.rows, 3);
        assert_eq!(
            footer.columns,
            vec![("cw_id".to_string(), "i64".to_string())]
        );
        assert_eq!(read_parquet(&path).unwrap(), df);
    }

    /// The hash taken on the way out is the file's, the bytes are those an
    /// atomic write gives, and no temporary is left beside the file.
    #[test]
    fn an_unpublished_write_hashes_what_it_wrote() {
        let dir = tempfile::tempdir().unwrap();
        let rows: Vec<i64> = (0..50_000).collect();
        let mut df = frame(vec![Column::new("cw_id".into(), rows)]);
        let unpublished = dir.path().join("entry").join("t.parquet");
        let hash = write_parquet_unpublished(&mut df, &unpublished, None).unwrap();
        assert_eq!(hash, crate::fsio::hash_file(&unpublished).unwrap());
        let atomic = dir.path().join("atomic.parquet");
        write_parquet(&mut df, &atomic, None).unwrap();
        assert_eq!(
            std::fs::read(&unpublished).unwrap(),
            std::fs::read(&atomic).unwrap()
        );
        assert_eq!(
            std::fs::read_dir(unpublished.parent().unwrap())
                .unwrap()
                .count(),
            1
        );
        assert_eq!(read_parquet(&unpublished).unwrap(), df);
    }

    #[test]
    fn content_hash_ignores_provenance_but_not_values() {
        let a = frame(vec![Column::new("x".into(), vec![1.0f64, 2.0])]);
        let b = frame(vec![Column::new("x".into(), vec![1.0f64, 2.5])]);
        let c = frame(vec![Column::new("y".into(), vec![1.0f64, 2.0])]);
        assert_eq!(content_hash(&a), content_hash(&a.clone()));
        assert_ne!(content_hash(&a), content_hash(&b));
        assert_ne!(content_hash(&a), content_hash(&c));
    }

    /// Buffering changes nothing: small pieces, pieces across the buffer's
    /// edge and pieces larger than it hash as the whole stream does.
    #[test]
    fn the_buffered_hasher_hashes_the_stream() {
        let stream: Vec<u8> = (0..300_000_u32).map(|i| (i * 7 % 251) as u8).collect();
        let mut buffered = BufferedHasher::default();
        let mut at = 0;
        for (k, piece) in [1, 8, 9, 70_000, 3, 100_000, 65_536]
            .iter()
            .cycle()
            .enumerate()
        {
            if at == stream.len() || k > 100 {
                break;
            }
            let end = (at + piece).min(stream.len());
            buffered.update(&stream[at..end]);
            at = end;
        }
        buffered.update(&stream[at..]);
        assert_eq!(buffered.finalize(), blake3::hash(&stream));
    }

    #[test]
    fn garbage_file_is_reported_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.parquet");
        std::fs::write(&path, b"not parquet at all").unwrap();
        let err = read_parquet(&path).unwrap_err().to_string();
        assert!(
            err.contains("bad.parquet") && err.contains("not a readable Parquet file"),
            "{err}"
        );
    }
}
