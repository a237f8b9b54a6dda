//! The content-addressed cache: one folder per cache key holding a stage's output
//! tables and a manifest, written last.
//!
//! An entry is built in a temporary folder (every file fsynced, the manifest
//! last), then renamed into place, so a kill at any instant leaves either no entry
//! or a complete one. Every hit re-hashes the files against the manifest; a
//! truncated or altered entry is reported, deleted and recomputed.

use std::collections::BTreeMap;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use polars::prelude::DataFrame;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::fsio::{self, sweep};
use crate::table::{self, Provenance};

/// One table of a cache entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CachedTable {
    pub file: String,
    /// Blake3 of the file's bytes: integrity.
    pub bytes_hash: String,
    /// Blake3 of the table's data (not its provenance): what downstream keys use.
    pub content_hash: String,
    pub rows: usize,
}

/// A non-table output of a cache entry (a report).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CachedFile {
    pub file: String,
    pub bytes_hash: String,
}

/// The manifest of a cache entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub key: String,
    pub stage_kind: String,
    pub tables: BTreeMap<String, CachedTable>,
    #[serde(default)]
    pub files: BTreeMap<String, CachedFile>,
    pub facts: BTreeMap<String, String>,
    pub created_at: String,
}

/// Why a cache entry was not usable.
#[derive(Debug, Clone, PartialEq)]
pub enum Lookup {
    Hit(Manifest),
    Miss,
    /// Present but damaged; the reason says which file and how.
    Corrupt(String),
}

pub struct Cache {
    root: PathBuf,
}

const MANIFEST: &str = "manifest.json";

impl Cache {
    pub fn new(root: PathBuf) -> Self {
        Cache { root }
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn entry_dir(&self, key: &str) -> PathBuf {
        self.root.join(&key[..2]).join(key)
    }

    pub fn table_path(&self, key: &str, table: &CachedTable) -> PathBuf {
        self.entry_dir(key).join(&table.file)
    }

    pub fn file_path(&self, key: &str, file: &CachedFile) -> PathBuf {
        self.entry_dir(key).join(&file.file)
    }

    /// Looks `key` up and verifies every file against the manifest.
    pub fn lookup(&self, key: &str) -> Lookup {
        let dir = self.entry_dir(key);
        let manifest_path = dir.join(MANIFEST);
        let text = match fs::read_to_string(&manifest_path) {
            Ok(t) => t,
            Err(_) if !dir.exists() => return Lookup::Miss,
            Err(e) => return Lookup::Corrupt(format!("manifest unreadable: {e}")),
        };
        let manifest: Manifest = match serde_json::from_str(&text) {
            Ok(m) => m,
            Err(e) => return Lookup::Corrupt(format!("manifest damaged: {e}")),
        };
        if manifest.key != key {
            return Lookup::Corrupt(format!("manifest is for key {}", manifest.key));
        }
        let stored = manifest
            .tables
            .values()
            .map(|t| (&t.file, &t.bytes_hash))
            .chain(manifest.files.values().map(|f| (&f.file, &f.bytes_hash)));
        for (file, expected) in stored {
            match fsio::hash_file(&dir.join(file)) {
                Ok(hash) if &hash == expected => {}
                Ok(_) => return Lookup::Corrupt(format!("{file} does not match its hash")),
                Err(e) => return Lookup::Corrupt(format!("{file}: {e}")),
            }
        }
        Lookup::Hit(manifest)
    }

    /// Deletes an entry (after it was found corrupt).
    pub fn remove(&self, key: &str) -> std::io::Result<()> {
        let dir = self.entry_dir(key);
        if dir.exists() {
            remove_entry(&dir, key)?;
        }
        Ok(())
    }

    /// Writes a new entry atomically and returns its manifest.
    pub fn store(
        &self,
        key: &str,
        stage_kind: &str,
        tables: &mut BTreeMap<String, DataFrame>,
        files: &BTreeMap<String, Vec<u8>>,
        facts: &BTreeMap<String, String>,
        provenance: &Provenance,
    ) -> Result<Manifest, table::TableError> {
        let final_dir = self.entry_dir(key);
        let parent = final_dir.parent().expect("entry has a parent");
        let tmp_dir = parent.join(sweep::cache_temp_name(key));
        let io = |e: std::io::Error| table::schema::io_error(&tmp_dir, e);
        if tmp_dir.exists() {
            fs::remove_dir_all(&tmp_dir).map_err(io)?;
        }
        fs::create_dir_all(&tmp_dir).map_err(io)?;
        let mut manifest = Manifest {
            key: key.to_string(),
            stage_kind: stage_kind.to_string(),
            tables: BTreeMap::new(),
            files: BTreeMap::new(),
            facts: facts.clone(),
            created_at: provenance.created_at.clone(),
        };
        // The entry's folder is private until it is renamed into place, so its
        // files need no temporaries of their own: each is fsynced, then every
        // folder they were made in once, then the rename publishes them all.
        // The tables on the threads: encoding and hashing them one after the
        // other took most of a small night's 10 ms of storing `identify`'s six.
        let stored: Vec<(String, PathBuf, CachedTable)> = tables
            .iter_mut()
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|(name, df)| {
                let file = format!("{name}.parquet");
                let path = tmp_dir.join(&file);
                let bytes_hash = table::write_parquet_unpublished(df, &path, Some(provenance))?;
                let table = CachedTable {
                    bytes_hash,
                    content_hash: table::content_hash(df),
                    rows: df.height(),
                    file,
                };
                Ok((name.clone(), path, table))
            })
            .collect::<Result<_, table::TableError>>()?;
        let mut written = Vec::new();
        for (name, path, table) in stored {
            manifest.tables.insert(name, table);
            written.push(path);
        }
        for (name, bytes) in files {
            let path = tmp_dir.join(name);
            fsio::write_unpublished(&path, |f| f.write_all(bytes)).map_err(io)?;
            manifest.files.insert(
                name.clone(),
                CachedFile {
                    file: name.clone(),
                    bytes_hash: blake3::hash(bytes).to_hex().to_string(),
                },
            );
            written.push(path);
        }
        let json = serde_json::to_vec_pretty(&manifest).expect("manifest serialises");
        fsio::write_unpublished(&tmp_dir.join(MANIFEST), |f| f.write_all(&json)).map_err(io)?;
        // Each folder a file was made in, and the folders between it and the
        // entry's (a file's own path may have folders: `robot_id=…/date=…/`).
        let folders = written.iter().flat_map(|path| {
            path.ancestors()
                .skip(1)
                .take_while(|dir| dir.starts_with(&tmp_dir))
        });
        fsio::sync_dirs(folders.chain([tmp_dir.as_path()])).map_err(io)?;
        if final_dir.exists() {
            fs::remove_dir_all(&final_dir).map_err(io)?;
        }
        fs::rename(&tmp_dir, &final_dir).map_err(io)?;
        fsio::sync_dir(parent).map_err(io)?;
        Ok(manifest)
    }

    /// Removes temporaries of dead writers (entries being built, entries being
    /// removed) from the shards. Complete entries are not entered: they were
    /// renamed into place after their last write, so they hold no temporaries.
    pub fn sweep(&self) -> std::io::Result<sweep::Swept> {
        let mut swept = sweep::Swept::default();
        let Ok(shards) = fs::read_dir(&self.root) else {
            return Ok(swept);
        };
        for shard in shards {
            let shard = shard?;
            if shard.file_type()?.is_dir() {
                swept.extend(sweep::sweep_folder(&shard.path())?);
            }
        }
        Ok(swept)
    }

    /// Removes entries whose key is not in `keep`. Returns (entries removed,
    /// bytes freed). Only folders named like a key are entries; temporaries of
    /// killed runs are left to [`Cache::sweep`], which knows whether their writer
    /// is dead.
    pub fn gc(&self, keep: &std::collections::HashSet<String>) -> std::io::Result<(usize, u64)> {
        let mut removed = 0;
        let mut freed = 0;
        let Ok(shards) = fs::read_dir(&self.root) else {
            return Ok((0, 0));
        };
        for shard in shards {
            let shard = shard?.path();
            if !shard.is_dir() {
                continue;
            }
            for entry in fs::read_dir(&shard)? {
                let path = entry?.path();
                let Some(key) = path.file_name().and_then(|n| n.to_str()) else {
                    continue;
                };
                if is_key(key) && path.is_dir() && !keep.contains(key) {
                    freed += dir_size(&path);
                    remove_entry(&path, key)?;
                    removed += 1;
                }
            }
        }
        Ok((removed, freed))
    }
}

/// A cache key: blake3 hex.
fn is_key(name: &str) -> bool {
    name.len() == 64 && name.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

/// Removes an entry folder so that it vanishes at once: renamed to a temporary
/// name first, then deleted. A kill during the (not atomic) deletion leaves a
/// temporary that the next sweep removes, never a half-deleted entry under its key.
fn remove_entry(dir: &Path, key: &str) -> std::io::Result<()> {
    let doomed = dir.with_file_name(sweep::cache_temp_name(key));
    if doomed.exists() {
        fs::remove_dir_all(&doomed)?;
    }
    fs::rename(dir, &doomed)?;
    fs::remove_dir_all(&doomed)
}

fn dir_size(path: &Path) -> u64 {
    fs::read_dir(path)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .map(|e| {
                    e.metadata().map_or(0, |m| {
                        if m.is_dir() {
                            dir_size(&e.path())
                        } else {
                            m.len()
                        }
                    })
                })
                .sum()
        })
        .unwrap_or(0)
}
