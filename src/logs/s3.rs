//! Logs in S3-compatible object storage (`s3://bucket/prefix`): listing the
//! partitions a query needs, objects' ETags and bodies, and the options polars
//! reads the objects with.
//!
//! Listing walks the `robot_id=…/date=…/` levels with a delimiter and descends
//! only into the prefixes the query keeps, so a night of one robot lists its two
//! weeks of folders, not the plant's years of objects. Endpoint, region and
//! `allow_http` come from the stage's `s3` settings, else from the `AWS_*`
//! variables (`AWS_ENDPOINT_URL`, `AWS_REGION`, `AWS_ALLOW_HTTP`); credentials
//! come from the `AWS_*` variables (`AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`,
//! `AWS_SESSION_TOKEN`), else from the shared credentials file
//! (`AWS_SHARED_CREDENTIALS_FILE`, default `~/.aws/credentials`; profile
//! `AWS_PROFILE`, default `default`), else from a web-identity or container
//! provider the `AWS_*` variables name, else from the instance-metadata service
//! of an EC2 machine — never from a job file. When none of them gives any, the
//! error says so and where they were looked for.
//!
//! Everything the client would build a URL from (the endpoint, the region, the
//! bucket, the prefix) is checked here first: the client library panics on a
//! malformed URL, so a bad value must be refused, naming the setting or the
//! variable, before it reaches the client.
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
        if let Err(message) = check_bucket(bucket) {
            return Some(Err(format!("`{url}`: {message}")));
        }
        if prefix.contains(['*', '?', '[']) {
            return Some(Err(format!(
                "`{url}`: globs are not supported on S3; give the prefix of the log folder"
            )));
        }
        let prefix = prefix.trim_matches('/');
        if let Err(message) = check_prefix(prefix) {
            return Some(Err(format!("`{url}`: {message}")));
        }
        Some(Ok(S3Location {
            bucket: bucket.to_string(),
            prefix: prefix.to_string(),
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
    credentials: Credentials,
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
    /// Checks the connection settings and the credentials, then builds the client
    /// (no request is made yet).
    pub fn connect(location: &S3Location, settings: &S3Settings) -> Result<S3Store, String> {
        check_connection(settings).map_err(|m| format!("S3 settings for {location}: {m}"))?;
        let credentials = find_credentials().map_err(|m| format!("{location}: {m}"))?;
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
        for (key, value) in credentials.config() {
            builder = builder.with_config(key, value);
        }
        let store = catch_panic(|| builder.build())
            .and_then(|built| built.map_err(|e| e.to_string()))
            .map_err(|e| format!("S3 settings for {location}: {e}"))?;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| format!("cannot start the S3 client: {e}"))?;
        Ok(S3Store {
            location: location.clone(),
            settings: settings.clone(),
            credentials,
            store,
            runtime,
        })
    }

    /// A failed request's message; when egcal found no credentials of its own and
    /// the request failed, says so first (the client's own error would only name
    /// the instance-metadata address it tried last).
    fn request_failed(&self, what: &str, error: String) -> String {
        match self.credentials {
            Credentials::InstanceMetadata => format!(
                "no S3 credentials found: {}; the instance-metadata service (EC2) gave none \
                 either ({what}: {})",
                WHERE_CREDENTIALS,
                short(&error)
            ),
            _ => format!("{what}: {error}"),
        }
    }

    /// `false` when egcal found no credentials and the client asks the
    /// instance-metadata service.
    pub fn found_credentials(&self) -> bool {
        self.credentials != Credentials::InstanceMetadata
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
            } = catch_panic(|| {
                self.runtime
                    .block_on(self.store.list_with_delimiter(folder.as_ref()))
                    .map_err(|e| e.to_string())
            })
            .and_then(|listed| listed)
            .map_err(|e| self.request_failed("cannot list", e))?;
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
        catch_panic(|| {
            self.runtime
                .block_on(async {
                    let got = self.store.get(&ObjectPath::from(key)).await?;
                    got.bytes().await
                })
                .map(|bytes| bytes.to_vec())
                .map_err(|e| e.to_string())
        })
        .and_then(|read| read)
        .map_err(|e| self.request_failed(&format!("reading {url}"), e))
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
        config.extend(self.credentials.config());
        CloudOptions::default().with_aws(config)
    }
}

/// Where credentials are looked for, for the message that found none.
const WHERE_CREDENTIALS: &str = "set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (and \
AWS_SESSION_TOKEN for temporary ones), or put aws_access_key_id and aws_secret_access_key \
in ~/.aws/credentials (AWS_SHARED_CREDENTIALS_FILE) under [default] or the profile \
AWS_PROFILE names";

/// Where the client's credentials come from.
#[derive(Debug, Clone, PartialEq)]
enum Credentials {
    /// A key pair (and token) from the variables or the credentials file.
    Static {
        key_id: String,
        secret: String,
        token: Option<String>,
    },
    /// A web-identity or container provider the `AWS_*` variables configure.
    Provider,
    /// Nothing found: only the instance-metadata service is left to ask.
    InstanceMetadata,
}

impl Credentials {
    fn config(&self) -> Vec<(AmazonS3ConfigKey, String)> {
        match self {
            Credentials::Static {
                key_id,
                secret,
                token,
            } => {
                let mut config = vec![
                    (AmazonS3ConfigKey::AccessKeyId, key_id.clone()),
                    (AmazonS3ConfigKey::SecretAccessKey, secret.clone()),
                ];
                config.extend(token.clone().map(|t| (AmazonS3ConfigKey::Token, t)));
                config
            }
            _ => Vec::new(),
        }
    }
}

/// A non-empty variable.
fn env(name: &str) -> Option<String> {
    std::env::var(name).ok().filter(|v| !v.trim().is_empty())
}

/// The credentials the client will use: the variables, the credentials file, a
/// configured provider, or none (instance metadata).
fn find_credentials() -> Result<Credentials, String> {
    match (env("AWS_ACCESS_KEY_ID"), env("AWS_SECRET_ACCESS_KEY")) {
        (Some(key_id), Some(secret)) => {
            return Ok(Credentials::Static {
                key_id,
                secret,
                token: env("AWS_SESSION_TOKEN"),
            });
        }
        (Some(_), None) => {
            return Err("AWS_ACCESS_KEY_ID is set but AWS_SECRET_ACCESS_KEY is not".into());
        }
        (None, Some(_)) => {
            return Err("AWS_SECRET_ACCESS_KEY is set but AWS_ACCESS_KEY_ID is not".into());
        }
        (None, None) => {}
    }
    let file = env("AWS_SHARED_CREDENTIALS_FILE")
        .map(std::path::PathBuf::from)
        .or_else(|| env("HOME").map(|home| std::path::Path::new(&home).join(".aws/credentials")));
    let profile = env("AWS_PROFILE");
    if let Some(file) = file {
        match std::fs::read_to_string(&file) {
            Ok(text) => {
                let name = profile.as_deref().unwrap_or("default");
                if let Some(found) = profile_credentials(&text, name) {
                    return found.map_err(|m| format!("{}: profile [{name}]: {m}", file.display()));
                }
                if profile.is_some() {
                    return Err(format!(
                        "the profile `{name}` that AWS_PROFILE names is not in {}",
                        file.display()
                    ));
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                if profile.is_some() {
                    return Err(format!(
                        "AWS_PROFILE is set but there is no credentials file {}",
                        file.display()
                    ));
                }
            }
            Err(e) => return Err(format!("cannot read {}: {e}", file.display())),
        }
    }
    let provider = env("AWS_WEB_IDENTITY_TOKEN_FILE").is_some()
        || env("AWS_CONTAINER_CREDENTIALS_RELATIVE_URI").is_some()
        || env("AWS_CONTAINER_CREDENTIALS_FULL_URI").is_some();
    Ok(if provider {
        Credentials::Provider
    } else {
        Credentials::InstanceMetadata
    })
}

/// The key pair of `[name]` in a credentials file's text: `None` when the file has
/// no such section, an error when the section lacks a key.
fn profile_credentials(text: &str, name: &str) -> Option<Result<Credentials, String>> {
    let mut section: Option<&str> = None;
    let mut found = false;
    let (mut key_id, mut secret, mut token) = (None, None, None);
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with(['#', ';']) {
            continue;
        }
        if let Some(header) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = Some(header.trim());
            found |= header.trim() == name;
            continue;
        }
        if section != Some(name) {
            continue;
        }
        if let Some((key, value)) = line.split_once('=') {
            let value = value.trim().to_string();
            match key.trim() {
                "aws_access_key_id" => key_id = Some(value),
                "aws_secret_access_key" => secret = Some(value),
                "aws_session_token" => token = Some(value),
                _ => {}
            }
        }
    }
    if !found {
        return None;
    }
    Some(match (key_id, secret) {
        (Some(key_id), Some(secret)) if !key_id.is_empty() && !secret.is_empty() => {
            Ok(Credentials::Static {
                key_id,
                secret,
                token,
            })
        }
        _ => Err("needs both aws_access_key_id and aws_secret_access_key".into()),
    })
}

/// The first line of a client error, without its retry details.
fn short(error: &str) -> &str {
    error.lines().next().unwrap_or(error)
}

/// Runs `f`, turning a panic of the client library into an error: the last guard
/// behind the checks of everything it is given.
fn catch_panic<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|panic| {
        let what = panic
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default();
        format!("the S3 client failed: {what}")
    })
}

/// A bucket name as S3 allows it: 3 to 63 lowercase letters, digits, `.` and `-`,
/// starting and ending with a letter or digit.
fn check_bucket(bucket: &str) -> Result<(), String> {
    let ok_chars = bucket
        .chars()
        .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '.' || c == '-');
    let ends = |c: Option<char>| c.is_some_and(|c| c.is_ascii_lowercase() || c.is_ascii_digit());
    if (3..=63).contains(&bucket.len())
        && ok_chars
        && ends(bucket.chars().next())
        && ends(bucket.chars().last())
        && !bucket.contains("..")
    {
        Ok(())
    } else {
        Err(format!(
            "`{bucket}` is not a bucket name (3 to 63 lowercase letters, digits, `.` and `-`, \
             starting and ending with a letter or digit)"
        ))
    }
}

/// A key prefix of plain segments: no `.` or `..` (object keys have no parent
/// folders), no empty segment (`//`), no control characters.
fn check_prefix(prefix: &str) -> Result<(), String> {
    if prefix.is_empty() {
        return Ok(());
    }
    for segment in prefix.split('/') {
        if segment.is_empty() {
            return Err("the prefix has an empty segment (`//`)".into());
        }
        if segment == "." || segment == ".." {
            return Err(format!(
                "the prefix has a `{segment}` segment; S3 keys have no relative folders: \
                 give the prefix as it is in the bucket"
            ));
        }
        if segment.chars().any(char::is_control) {
            return Err("the prefix holds a control character".into());
        }
    }
    Ok(())
}

/// An endpoint URL: `http://` or `https://`, a host, an optional port and path;
/// ASCII without spaces, no user, query or fragment.
fn check_endpoint(text: &str) -> Result<reqwest::Url, String> {
    let expected = "expected an http:// or https:// URL such as `http://127.0.0.1:3900`";
    if text.is_empty() || !text.chars().all(|c| c.is_ascii_graphic()) {
        return Err(format!(
            "`{text}` is not a URL (spaces or non-ASCII characters); {expected}"
        ));
    }
    let url = reqwest::Url::parse(text)
        .map_err(|e| format!("`{text}` is not a URL ({e}); {expected}"))?;
    if !matches!(url.scheme(), "http" | "https") {
        return Err(format!(
            "`{text}` has the scheme `{}`; {expected}",
            url.scheme()
        ));
    }
    if url.host_str().is_none_or(str::is_empty) {
        return Err(format!("`{text}` names no host; {expected}"));
    }
    if !url.username().is_empty() || url.password().is_some() {
        return Err(format!(
            "`{text}` holds a user name; credentials come from the AWS_* variables or ~/.aws/credentials"
        ));
    }
    if url.query().is_some() || url.fragment().is_some() {
        return Err(format!("`{text}` has a query or fragment; {expected}"));
    }
    Ok(url)
}

/// A region name: letters, digits, `-`, `_` and `.` (e.g. `eu-west-1`, `garage`).
fn check_region(text: &str) -> Result<(), String> {
    if !text.is_empty()
        && text.len() <= 64
        && text
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
    {
        Ok(())
    } else {
        Err(format!(
            "`{text}` is not a region name (letters, digits, `-`, `_`, `.`; e.g. `eu-west-1`)"
        ))
    }
}

impl S3Settings {
    /// Problems of the settings as written, as (key below the stage, message):
    /// what can be checked without the environment.
    pub fn problems(&self, key: &str) -> Vec<(String, String)> {
        let mut problems = Vec::new();
        if let Some(endpoint) = &self.endpoint {
            match check_endpoint(endpoint) {
                Err(message) => problems.push((format!("{key}.endpoint"), message)),
                Ok(url) if url.scheme() == "http" && self.allow_http == Some(false) => problems
                    .push((
                        format!("{key}.allow_http"),
                        format!("is false but the endpoint `{endpoint}` is plain HTTP"),
                    )),
                Ok(_) => {}
            }
        }
        if let Some(region) = &self.region
            && let Err(message) = check_region(region)
        {
            problems.push((format!("{key}.region"), message));
        }
        problems
    }
}

/// The effective endpoint, region and plain-HTTP permission (settings over the
/// `AWS_*` variables), each checked and a problem named by where it came from.
fn check_connection(settings: &S3Settings) -> Result<(), String> {
    if let Some((key, message)) = settings.problems("s3").into_iter().next() {
        return Err(format!("`{key}`: {message}"));
    }
    let endpoint = match &settings.endpoint {
        Some(endpoint) => Some(("`s3.endpoint`", endpoint.clone())),
        None => ["AWS_ENDPOINT_URL_S3", "AWS_ENDPOINT_URL", "AWS_ENDPOINT"]
            .into_iter()
            .find_map(|name| env(name).map(|v| (name, v))),
    };
    if let Some((source, endpoint)) = endpoint {
        let url = check_endpoint(&endpoint).map_err(|m| format!("{source}: {m}"))?;
        if url.scheme() == "http" {
            let allowed = match settings.allow_http {
                Some(allow) => allow,
                None => env("AWS_ALLOW_HTTP").is_some_and(|v| v.eq_ignore_ascii_case("true")),
            };
            if !allowed {
                return Err(format!(
                    "{source}: `{endpoint}` is plain HTTP; set `s3.allow_http = true` (or \
                     AWS_ALLOW_HTTP=true) to allow it, e.g. for a server on loopback"
                ));
            }
        }
    }
    if settings.region.is_none() {
        for name in ["AWS_REGION", "AWS_DEFAULT_REGION"] {
            if let Some(region) = env(name) {
                check_region(&region).map_err(|m| format!("{name}: {m}"))?;
            }
        }
    }
    if let Some(allow) = env("AWS_ALLOW_HTTP")
        && settings.allow_http.is_none()
        && !["true", "false"]
            .iter()
            .any(|v| allow.eq_ignore_ascii_case(v))
    {
        return Err(format!("AWS_ALLOW_HTTP: `{allow}` is not true or false"));
    }
    Ok(())
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

    #[test]
    fn odd_buckets_and_prefixes_are_refused_before_the_client() {
        for bad in [
            "s3://",
            "s3://bucket/../x",
            "s3://bucket/a/./b",
            "s3://bucket/a//b",
            "s3://Bucket/x",
            "s3://a b/x",
            "s3://ab/x",
            "s3://bucket?x=1/y",
            "s3://-bucket/x",
        ] {
            let message = S3Location::parse(bad).unwrap().unwrap_err();
            assert!(message.contains('`'), "{bad}: {message}");
        }
        assert!(
            S3Location::parse("s3://egcal-test/tests/1-2/logs")
                .unwrap()
                .is_ok()
        );
    }

    #[test]
    fn endpoints_and_regions_are_checked() {
        for bad in [
            "not a url",
            "ftp://x",
            "http://",
            "http://u:p@h",
            "127.0.0.1:3900",
            "http://h/?a",
            "http://mü.de",
        ] {
            assert!(check_endpoint(bad).is_err(), "{bad}");
        }
        for good in [
            "http://127.0.0.1:3900",
            "https://s3.example.com/base",
            "http://[::1]:9000",
        ] {
            assert!(check_endpoint(good).is_ok(), "{good}");
        }
        let settings = S3Settings {
            endpoint: Some("not a url".into()),
            region: Some("eu west".into()),
            allow_http: None,
        };
        let keys: Vec<String> = settings
            .problems("s3")
            .into_iter()
            .map(|(k, _)| k)
            .collect();
        assert_eq!(keys, ["s3.endpoint", "s3.region"]);
    }

    #[test]
    fn credentials_file_profiles() {
        let text = "[default]\naws_access_key_id = A\naws_secret_access_key = B\n\n[night]\naws_access_key_id=C\n";
        assert_eq!(
            profile_credentials(text, "default"),
            Some(Ok(Credentials::Static {
                key_id: "A".into(),
                secret: "B".into(),
                token: None
            }))
        );
        assert!(profile_credentials(text, "night").unwrap().is_err());
        assert!(profile_credentials(text, "other").is_none());
    }
}
