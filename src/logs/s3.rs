//! Logs in S3-compatible object storage (`s3://bucket/prefix`): listing the
//! partitions a query needs, objects' ETags and bodies, and the options polars
//! reads the objects with.
//!
//! Listing walks the `robot_id=…/date=…/` levels with a delimiter and descends
//! only into the prefixes the query keeps, so a night of one robot lists its two
//! weeks of folders, not the plant's years of objects. Endpoint, region and
//! `allow_http` come from the stage's `s3` settings, else from the `AWS_*`
//! variables (`AWS_ENDPOINT_URL`, `AWS_REGION`, `AWS_ALLOW_HTTP`); credentials
//! come from the `AWS_*` variables only (`AWS_ACCESS_KEY_ID`,
//! `AWS_SECRET_ACCESS_KEY`, `AWS_SESSION_TOKEN`), never from a job file.
//!
//! object_store is the client polars itself uses for cloud reads; it needs a
//! tokio runtime, kept here and never entered while polars runs.

use object_store::ObjectStoreExt;
use object_store::aws::{AmazonS3, AmazonS3Builder, AmazonS3ConfigKey};
use object_store::path::Path as ObjectPath;
use object_store::{ListResult, ObjectStore};
use polars::prelude::cloud::CloudOptions;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Connection settings that may differ per job (e.g. several object stores).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct S3Settings {
    /// Endpoint URL of an S3-compatible server, e.g. `http://127.0.0.1:3900`;
    /// default `AWS_ENDPOINT_URL`, else Amazon S3.
    pub endpoint: Option<String>,
    /// Region; default `AWS_REGION` (or `AWS_DEFAULT_REGION`).
    pub region: Option<String>,
    /// Allow a plain-HTTP endpoint (a server on loopback); default `AWS_ALLOW_HTTP`.
    pub allow_http: Option<bool>,
}

/// An `s3://bucket/prefix` address.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct S3Location {
    pub bucket: String,
    /// Key prefix without leading or trailing `/` (empty: the whole bucket).
    pub prefix: String,
}

impl S3Location {
    /// Parses `s3://bucket[/prefix]`; `None` for any other text.
    pub fn parse(url: &str) -> Option<Result<S3Location, String>> {
        let rest = url.strip_prefix("s3://")?;
        let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
        if bucket.is_empty() {
            return Some(Err(format!("`{url}` names no bucket (s3://bucket/prefix)")));
        }
        if prefix.contains(['*', '?', '[']) {
            return Some(Err(format!(
                "`{url}`: globs are not supported on S3; give the prefix of the log folder"
            )));
        }
        Some(Ok(S3Location {
            bucket: bucket.to_string(),
            prefix: prefix.trim_matches('/').to_string(),
        }))
    }

    /// The `s3://` URL of a key of this bucket.
    pub fn url_of(&self, key: &str) -> String {
        format!("s3://{}/{key}", self.bucket)
    }

    /// `key` below the prefix.
    pub fn relative<'a>(&self, key: &'a str) -> &'a str {
        key.strip_prefix(&self.prefix)
            .map(|k| k.trim_start_matches('/'))
            .unwrap_or(key)
    }
}

impl std::fmt::Display for S3Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "s3://{}/{}", self.bucket, self.prefix)
    }
}

/// One listed object.
#[derive(Debug, Clone, PartialEq)]
pub struct S3Object {
    pub key: String,
    pub e_tag: Option<String>,
    pub size: u64,
}

/// What a pruned walk found.
#[derive(Debug, Clone, Default)]
pub struct Listing {
    pub objects: Vec<S3Object>,
    /// Folders (common prefixes) the walk did not enter.
    pub folders_pruned: usize,
    /// Last path segments of every folder seen, entered or not (`robot_id=r1`).
    pub folders_seen: Vec<String>,
}

/// A connected bucket.
pub struct S3Store {
    location: S3Location,
    settings: S3Settings,
    store: AmazonS3,
    runtime: tokio::runtime::Runtime,
}

impl std::fmt::Debug for S3Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("S3Store")
            .field("location", &self.location)
            .finish_non_exhaustive()
    }
}

/// Deepest folder level a walk descends (a log layout has two or three).
const MAX_DEPTH: usize = 12;

impl S3Store {
    pub fn connect(location: &S3Location, settings: &S3Settings) -> Result<S3Store, String> {
        let mut builder = AmazonS3Builder::from_env().with_bucket_name(&location.bucket);
        for (key, value) in explicit_config(settings) {
            builder = builder.with_config(key, value);
        }
        if builder
            .get_config_value(&AmazonS3ConfigKey::Region)
            .is_none()
            && let Ok(region) = std::env::var("AWS_DEFAULT_REGION")
        {
            builder = builder.with_region(region);
        }
        let store = builder
            .build()
            .map_err(|e| format!("S3 settings for {location}: {e}"))?;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| format!("cannot start the S3 client: {e}"))?;
        Ok(S3Store {
            location: location.clone(),
            settings: settings.clone(),
            store,
            runtime,
        })
    }

    pub fn location(&self) -> &S3Location {
        &self.location
    }

    /// Every object below the prefix, entering a folder only when `enter` keeps its
    /// last segment (e.g. `robot_id=r1`).
    pub fn list(&self, enter: &dyn Fn(&str) -> bool) -> Result<Listing, String> {
        let mut listing = Listing::default();
        let root = (!self.location.prefix.is_empty())
            .then(|| ObjectPath::from(format!("{}/", self.location.prefix)));
        let mut pending = vec![(root, 0usize)];
        while let Some((folder, depth)) = pending.pop() {
            let ListResult {
                common_prefixes,
                objects,
            } = self
                .runtime
                .block_on(self.store.list_with_delimiter(folder.as_ref()))
                .map_err(|e| format!("cannot list: {e}"))?;
            listing
                .objects
                .extend(objects.into_iter().map(|meta| S3Object {
                    key: meta.location.to_string(),
                    e_tag: meta.e_tag,
                    size: meta.size,
                }));
            for prefix in common_prefixes {
                let segment = prefix.filename().unwrap_or_default().to_string();
                listing.folders_seen.push(segment.clone());
                if depth < MAX_DEPTH && enter(&segment) {
                    pending.push((Some(prefix), depth + 1));
                } else {
                    listing.folders_pruned += 1;
                }
            }
        }
        listing.objects.sort_by(|a, b| a.key.cmp(&b.key));
        Ok(listing)
    }

    /// An object's body.
    pub fn read(&self, key: &str) -> Result<Vec<u8>, String> {
        let url = self.location.url_of(key);
        self.runtime
            .block_on(async {
                let got = self.store.get(&ObjectPath::from(key)).await?;
                got.bytes().await
            })
            .map(|bytes| bytes.to_vec())
            .map_err(|e| format!("reading {url}: {e}"))
    }

    /// Options for polars to read this bucket's objects with the same settings
    /// (polars also reads the `AWS_*` variables).
    pub fn cloud_options(&self) -> CloudOptions {
        let mut config = explicit_config(&self.settings);
        let has_region = config.iter().any(|(k, _)| *k == AmazonS3ConfigKey::Region);
        if !has_region
            && std::env::var("AWS_REGION").is_err()
            && let Ok(region) = std::env::var("AWS_DEFAULT_REGION")
        {
            config.push((AmazonS3ConfigKey::Region, region));
        }
        CloudOptions::default().with_aws(config)
    }
}

/// The stage's own settings as object_store configuration keys.
fn explicit_config(settings: &S3Settings) -> Vec<(AmazonS3ConfigKey, String)> {
    let mut config = Vec::new();
    if let Some(endpoint) = &settings.endpoint {
        config.push((AmazonS3ConfigKey::Endpoint, endpoint.clone()));
    }
    if let Some(region) = &settings.region {
        config.push((AmazonS3ConfigKey::Region, region.clone()));
    }
    if let Some(allow) = settings.allow_http {
        config.push((
            AmazonS3ConfigKey::Client(object_store::ClientConfigKey::AllowHttp),
            allow.to_string(),
        ));
    }
    config
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_bucket_and_prefix() {
        let at = S3Location::parse("s3://logs/plant/cell_1/")
            .unwrap()
            .unwrap();
        assert_eq!(at.bucket, "logs");
        assert_eq!(at.prefix, "plant/cell_1");
        assert_eq!(
            at.relative("plant/cell_1/robot_id=a/x.parquet"),
            "robot_id=a/x.parquet"
        );
        assert_eq!(S3Location::parse("s3://logs").unwrap().unwrap().prefix, "");
        assert!(S3Location::parse("/data/logs").is_none());
        assert!(S3Location::parse("s3:///x").unwrap().is_err());
        assert!(S3Location::parse("s3://b/logs/*/x").unwrap().is_err());
    }
}
