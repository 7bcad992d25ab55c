//! The content-addressed asset store that replicas share (`serve --store URL`), through the
//! `object_store` crate: a local or mounted folder (`file:///path`) or S3-compatible storage
//! (`s3://bucket[/prefix]`, configured by the standard `AWS_*` variables).
//!
//! Layout under the store's root:
//! - `sha256/<hex>.lfa`: an asset file, named by the SHA-256 of its bytes. A key never changes
//!   content, so any replica may cache it for ever; a writer that finds it there (at the right
//!   length) does not send it again.
//! - `names/<id>.json`: `{"sha256": "<hex>", "bytes": N}`, which content an asset id names.
//!   Written create-only too (an id is not rebound while it exists), removed when the asset is
//!   deleted; the content object stays (other ids may name it).
//!
//! Every object read is verified: its length and SHA-256 must be what its name says, or the
//! fetch fails with [`StoreError::HashMismatch`] and nothing is kept. Each replica keeps what it
//! fetched in a local cache folder of at most `cache_limit` bytes; the least recently used files
//! that no loaded asset holds are evicted first.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, SystemTime};

use futures_util::StreamExt;
use object_store::aws::AmazonS3Builder;
use object_store::local::LocalFileSystem;
use object_store::path::Path as Key;
use object_store::prefix::PrefixStore;
use object_store::{ClientOptions, ObjectStore, PutMode, PutPayload, RetryConfig};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use tokio::io::AsyncWriteExt;

use super::assets::{describe_bytes, validate_id};

/// Largest name record read from the store: a record is about 100 bytes.
const MAX_RECORD_BYTES: u64 = 4096;

/// Files above this many bytes are published in parts of this size (S3 allows 5 MiB to 5 GiB
/// per part and 10,000 parts: 160 GiB at this size).
pub const MULTIPART_BYTES: usize = 16 << 20;

/// Parts of one multipart upload in flight at once (memory: this many parts).
const MULTIPART_PARALLEL: usize = 4;

/// The record of the file at `path`: its SHA-256 and length, read in 1 MiB pieces.
fn hash_file(path: &Path) -> std::io::Result<Record> {
    use std::io::Read;
    let mut file = std::fs::File::open(path)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut bytes = 0u64;
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
        bytes += n as u64;
    }
    Ok(Record {
        sha256: hex(&hasher.finalize()),
        bytes,
    })
}

/// Why a store operation failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// The `--store` URL cannot be used.
    #[error("bad --store {url:?}: {why}")]
    Config {
        /// The URL as given.
        url: String,
        /// What is wrong with it.
        why: String,
    },
    /// The store refused the credentials (401/403).
    #[error(
        "the asset store {store} refused the credentials ({op} {key}): {error} (check \
         AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY and the bucket's policy)"
    )]
    Credentials {
        /// The store URL.
        store: String,
        /// The operation.
        op: &'static str,
        /// The object key.
        key: String,
        /// The store's error.
        error: Box<object_store::Error>,
    },
    /// The store could not be reached or answered an error.
    #[error("the asset store {store} failed to {op} {key}: {error}")]
    Backend {
        /// The store URL.
        store: String,
        /// The operation.
        op: &'static str,
        /// The object key.
        key: String,
        /// The store's error.
        error: Box<object_store::Error>,
    },
    /// An object's content is not what its name says.
    #[error(
        "the asset store {store} holds a corrupt object: {key} is {actual_bytes} bytes with \
         SHA-256 {actual}, but its name says {expected_bytes} bytes with SHA-256 {expected}"
    )]
    HashMismatch {
        /// The store URL.
        store: String,
        /// The object key.
        key: String,
        /// The hash its name records.
        expected: String,
        /// The hash of the bytes read.
        actual: String,
        /// The length its name records.
        expected_bytes: u64,
        /// The number of bytes read (reading stops past the expected length).
        actual_bytes: u64,
    },
    /// A name record is not a valid record.
    #[error("the asset store {store} holds a bad record {key}: {why}")]
    BadRecord {
        /// The store URL.
        store: String,
        /// The object key.
        key: String,
        /// What is wrong with it.
        why: String,
    },
    /// The id already names other content.
    #[error(
        "asset id {id:?} is taken in the asset store {store} (it names content {existing}): \
         delete it first or choose another id"
    )]
    NameTaken {
        /// The store URL.
        store: String,
        /// The asset id.
        id: String,
        /// The SHA-256 it names.
        existing: String,
    },
    /// The asset is larger than the whole local cache.
    #[error(
        "asset {id:?} is {}, larger than this replica's store cache of {} (--store-cache-bytes)",
        describe_bytes(*bytes), describe_bytes(*limit)
    )]
    TooLarge {
        /// The asset id.
        id: String,
        /// Its size.
        bytes: u64,
        /// The cache's bound.
        limit: u64,
    },
    /// The local cache folder or a local file failed.
    #[error("{what} {}: {error}", path.display())]
    Local {
        /// What was being done.
        what: &'static str,
        /// The file or folder.
        path: PathBuf,
        /// The I/O error.
        error: std::io::Error,
    },
}

/// What an asset id names: `names/<id>.json`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Record {
    /// SHA-256 of the asset file, 64 lowercase hex digits.
    pub sha256: String,
    /// Length of the asset file in bytes.
    pub bytes: u64,
}

fn is_sha256_hex(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

fn hex(digest: &[u8]) -> String {
    use std::fmt::Write;
    digest.iter().fold(String::with_capacity(64), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

/// The store, and this replica's cache of it.
pub struct ContentStore {
    store: Arc<dyn ObjectStore>,
    url: String,
    cache_dir: PathBuf,
    cache_limit: u64,
    /// Distinguishes this process's temporary cache files.
    temp_counter: AtomicU64,
}

impl std::fmt::Debug for ContentStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContentStore")
            .field("url", &self.url)
            .field("cache_dir", &self.cache_dir)
            .field("cache_limit", &self.cache_limit)
            .finish_non_exhaustive()
    }
}

impl ContentStore {
    /// Opens the store at `url` with a cache in `cache_dir` (created) of at most `cache_limit`
    /// bytes, and removes the temporary files an interrupted fetch left in the cache. Nothing
    /// is sent to the store yet: [`Self::list_names`] is the first request (the readiness
    /// check).
    ///
    /// `file:///ABS/PATH` is a folder (created if missing); `s3://BUCKET[/PREFIX]` is S3 or an
    /// S3-compatible service, with credentials, region and endpoint from `AWS_ACCESS_KEY_ID`,
    /// `AWS_SECRET_ACCESS_KEY`, `AWS_SESSION_TOKEN`, `AWS_REGION` and `AWS_ENDPOINT_URL` (an
    /// `http://` endpoint is allowed as given).
    ///
    /// # Errors
    /// [`StoreError::Config`] for a URL that names no usable store; [`StoreError::Local`] when
    /// the folder or the cache cannot be created.
    pub fn open(url: &str, cache_dir: PathBuf, cache_limit: u64) -> Result<Self, StoreError> {
        let config = |why: String| StoreError::Config {
            url: url.to_owned(),
            why,
        };
        let store: Arc<dyn ObjectStore> = if let Some(path) = url.strip_prefix("file://") {
            let path = Path::new(path);
            if !path.is_absolute() {
                return Err(config(
                    "a file store needs an absolute path: file:///srv/assets".to_owned(),
                ));
            }
            std::fs::create_dir_all(path).map_err(|error| StoreError::Local {
                what: "creating the store folder",
                path: path.to_path_buf(),
                error,
            })?;
            Arc::new(
                LocalFileSystem::new_with_prefix(path)
                    .map_err(|e| config(e.to_string()))?
                    .with_automatic_cleanup(false),
            )
        } else if let Some(rest) = url.strip_prefix("s3://") {
            let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
            if bucket.is_empty() {
                return Err(config("no bucket: s3://BUCKET[/PREFIX]".to_owned()));
            }
            let endpoint = std::env::var("AWS_ENDPOINT_URL")
                .or_else(|_| std::env::var("AWS_ENDPOINT"))
                .unwrap_or_default();
            // Few, short retries: a store that does not answer should show in /readyz within
            // seconds, not after the crate's default three minutes of backoff.
            let retry = RetryConfig {
                max_retries: 2,
                retry_timeout: Duration::from_secs(15),
                ..RetryConfig::default()
            };
            let client = ClientOptions::new()
                .with_connect_timeout(Duration::from_secs(5))
                .with_timeout(Duration::from_secs(600))
                .with_allow_http(endpoint.starts_with("http://"));
            let s3 = AmazonS3Builder::from_env()
                .with_bucket_name(bucket)
                .with_retry(retry)
                .with_client_options(client)
                .build()
                .map_err(|e| config(e.to_string()))?;
            let prefix = prefix.trim_matches('/');
            if prefix.is_empty() {
                Arc::new(s3)
            } else {
                Arc::new(PrefixStore::new(s3, prefix))
            }
        } else {
            return Err(config(
                "the store must be file:///ABS/PATH or s3://BUCKET[/PREFIX]".to_owned(),
            ));
        };
        let blobs = cache_dir.join("sha256");
        std::fs::create_dir_all(&blobs).map_err(|error| StoreError::Local {
            what: "creating the store cache",
            path: blobs.clone(),
            error,
        })?;
        let this = Self {
            store,
            url: url.to_owned(),
            cache_dir,
            cache_limit,
            temp_counter: AtomicU64::new(0),
        };
        this.remove_temporaries();
        Ok(this)
    }

    /// The store's URL.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// The cache's bound in bytes.
    pub fn cache_limit(&self) -> u64 {
        self.cache_limit
    }

    fn backend(&self, op: &'static str, key: &Key, error: object_store::Error) -> StoreError {
        match error {
            error if is_refusal(&error) => StoreError::Credentials {
                store: self.url.clone(),
                op,
                key: key.to_string(),
                error: Box::new(error),
            },
            error => StoreError::Backend {
                store: self.url.clone(),
                op,
                key: key.to_string(),
                error: Box::new(error),
            },
        }
    }

    fn name_key(id: &str) -> Key {
        Key::from(format!("names/{id}.json"))
    }

    fn blob_key(sha256: &str) -> Key {
        Key::from(format!("sha256/{sha256}.lfa"))
    }

    /// Where the content `sha256` is cached.
    pub fn cache_path(&self, sha256: &str) -> PathBuf {
        self.cache_dir.join("sha256").join(format!("{sha256}.lfa"))
    }

    /// Every asset id the store names, sorted; keys that are not `names/<valid id>.json` are
    /// logged and skipped. This is the readiness check: it fails when the store cannot be
    /// reached, the bucket does not exist or the credentials are refused.
    ///
    /// # Errors
    /// [`StoreError::Credentials`] or [`StoreError::Backend`].
    pub async fn list_names(&self) -> Result<Vec<String>, StoreError> {
        let prefix = Key::from("names");
        let mut listing = self.store.list(Some(&prefix));
        let mut ids = Vec::new();
        while let Some(meta) = listing.next().await {
            let meta = meta.map_err(|e| self.backend("list", &prefix, e))?;
            let id = meta
                .location
                .filename()
                .and_then(|name| name.strip_suffix(".json"))
                .filter(|id| validate_id(id).is_ok());
            match id {
                Some(id) if meta.location.parts().count() == 2 => ids.push(id.to_owned()),
                _ => {
                    tracing::warn!(store = self.url, key = %meta.location, "skipping a key under names/ that is not names/<asset id>.json");
                }
            }
        }
        ids.sort();
        Ok(ids)
    }

    /// What `id` names, or `None` when the store has no such id.
    ///
    /// # Errors
    /// The store fails, or the record is not a valid record.
    pub async fn resolve(&self, id: &str) -> Result<Option<Record>, StoreError> {
        let key = Self::name_key(id);
        let got = match self.store.get(&key).await {
            Ok(got) => got,
            Err(object_store::Error::NotFound { .. }) => return Ok(None),
            Err(e) => return Err(self.backend("read", &key, e)),
        };
        let bad = |why: String| StoreError::BadRecord {
            store: self.url.clone(),
            key: key.to_string(),
            why,
        };
        if got.meta.size > MAX_RECORD_BYTES {
            return Err(bad(format!(
                "{} bytes, more than a record's {MAX_RECORD_BYTES}",
                got.meta.size
            )));
        }
        let bytes = got
            .bytes()
            .await
            .map_err(|e| self.backend("read", &key, e))?;
        let record: Record =
            serde_json::from_slice(&bytes).map_err(|e| bad(format!("not a record: {e}")))?;
        if !is_sha256_hex(&record.sha256) {
            return Err(bad(format!(
                "{:?} is not 64 lowercase hex digits",
                record.sha256.chars().take(80).collect::<String>()
            )));
        }
        Ok(Some(record))
    }

    /// The cached file of `record`, fetched from the store and verified first when it is not
    /// cached yet; then the cache is trimmed to its bound, keeping `pinned` (the files loaded
    /// assets use) and the file returned.
    ///
    /// # Errors
    /// [`StoreError::TooLarge`] before anything is read when the asset alone exceeds the cache;
    /// [`StoreError::HashMismatch`] when the object's bytes are not the recorded ones (nothing
    /// is kept); the store or the cache folder fails.
    pub async fn fetch(
        &self,
        id: &str,
        record: &Record,
        pinned: &HashSet<PathBuf>,
    ) -> Result<PathBuf, StoreError> {
        let path = self.cache_path(&record.sha256);
        let cached = tokio::fs::metadata(&path)
            .await
            .is_ok_and(|m| m.is_file() && m.len() == record.bytes);
        if cached {
            // The modification time orders the cache for eviction: a hit is a use.
            let touch = path.clone();
            let _ = tokio::task::spawn_blocking(move || {
                std::fs::File::options()
                    .append(true)
                    .open(&touch)
                    .and_then(|f| f.set_modified(SystemTime::now()))
            })
            .await;
        } else {
            if record.bytes > self.cache_limit {
                return Err(StoreError::TooLarge {
                    id: id.to_owned(),
                    bytes: record.bytes,
                    limit: self.cache_limit,
                });
            }
            self.download(record, &path).await?;
            tracing::info!(
                store = self.url,
                id,
                sha256 = record.sha256,
                bytes = record.bytes,
                "asset fetched from the store"
            );
        }
        let mut keep = pinned.clone();
        keep.insert(path.clone());
        let dir = self.cache_dir.join("sha256");
        let limit = self.cache_limit;
        tokio::task::spawn_blocking(move || evict(&dir, limit, &keep))
            .await
            .map_err(|e| StoreError::Local {
                what: "trimming the store cache",
                path: self.cache_dir.clone(),
                error: std::io::Error::other(e),
            })?
            .map_err(|error| StoreError::Local {
                what: "trimming the store cache",
                path: self.cache_dir.clone(),
                error,
            })?;
        Ok(path)
    }

    /// Streams `sha256/<hex>.lfa` into a temporary file next to `path`, hashing as it goes,
    /// and renames it to `path` only when length and hash match the record.
    async fn download(&self, record: &Record, path: &Path) -> Result<(), StoreError> {
        let key = Self::blob_key(&record.sha256);
        let got = self
            .store
            .get(&key)
            .await
            .map_err(|e| self.backend("read", &key, e))?;
        let n = self.temp_counter.fetch_add(1, Ordering::Relaxed);
        let temp = path.with_file_name(format!(
            ".{}.lfa.tmp-{}-{n}",
            record.sha256,
            std::process::id()
        ));
        let local = |what: &'static str, error: std::io::Error| StoreError::Local {
            what,
            path: temp.clone(),
            error,
        };
        let guard = RemoveOnDrop(Some(temp.clone()));
        let mut file = tokio::fs::File::create(&temp)
            .await
            .map_err(|e| local("creating", e))?;
        let mut hasher = Sha256::new();
        let mut read = 0u64;
        let mut stream = got.into_stream();
        while let Some(chunk) = stream.next().await {
            let chunk = chunk.map_err(|e| self.backend("read", &key, e))?;
            read += chunk.len() as u64;
            if read > record.bytes {
                // Longer than recorded: no need to read (or store) the rest.
                break;
            }
            hasher.update(&chunk);
            file.write_all(&chunk)
                .await
                .map_err(|e| local("writing", e))?;
        }
        let actual = hex(&hasher.finalize());
        if read != record.bytes || actual != record.sha256 {
            return Err(StoreError::HashMismatch {
                store: self.url.clone(),
                key: key.to_string(),
                expected: record.sha256.clone(),
                actual,
                expected_bytes: record.bytes,
                actual_bytes: read,
            });
        }
        file.sync_all().await.map_err(|e| local("syncing", e))?;
        drop(file);
        tokio::fs::rename(&temp, path)
            .await
            .map_err(|e| local("renaming", e))?;
        let mut guard = guard;
        guard.0 = None;
        Ok(())
    }

    /// Publishes the asset file at `path` as `id`: its content under its hash, then the name
    /// (create-only). Publishing the same content under the same id again succeeds. The file is
    /// read twice (hashed, then sent) and never held in memory whole: files above
    /// [`MULTIPART_BYTES`] go up in parts of that size, at most `MULTIPART_PARALLEL` at once.
    ///
    /// The content is always sent, not skipped when its key exists: a concurrent writer of the
    /// key can only put the same bytes, and an object there that was damaged (which its length
    /// alone would not show) is replaced by a good one.
    ///
    /// # Errors
    /// [`StoreError::NameTaken`] when `id` names other content; the store or the file fails.
    pub async fn publish(&self, id: &str, path: &Path) -> Result<Record, StoreError> {
        let local = |what: &'static str, error: std::io::Error| StoreError::Local {
            what,
            path: path.to_path_buf(),
            error,
        };
        let hashed = path.to_path_buf();
        let record = tokio::task::spawn_blocking(move || hash_file(&hashed))
            .await
            .map_err(|e| local("hashing", std::io::Error::other(e)))?
            .map_err(|e| local("hashing", e))?;
        self.upload(path, &Self::blob_key(&record.sha256), record.bytes)
            .await?;
        let name = Self::name_key(id);
        let body = serde_json::to_vec(&record).unwrap_or_default();
        match self
            .store
            .put_opts(&name, PutPayload::from(body), PutMode::Create.into())
            .await
        {
            Ok(_) => {}
            Err(object_store::Error::AlreadyExists { .. }) => match self.resolve(id).await? {
                Some(existing) if existing == record => {}
                Some(existing) => {
                    return Err(StoreError::NameTaken {
                        store: self.url.clone(),
                        id: id.to_owned(),
                        existing: existing.sha256,
                    });
                }
                // Deleted between the two requests: publish again once.
                None => {
                    let body = serde_json::to_vec(&record).unwrap_or_default();
                    self.store
                        .put_opts(&name, PutPayload::from(body), PutMode::Create.into())
                        .await
                        .map_err(|e| self.backend("write", &name, e))?;
                }
            },
            Err(e) => return Err(self.backend("write", &name, e)),
        }
        tracing::info!(
            store = self.url,
            id,
            sha256 = record.sha256,
            bytes = record.bytes,
            "asset published to the store"
        );
        Ok(record)
    }

    /// Sends the file at `path` (`bytes` long) to `key`: one request up to
    /// [`MULTIPART_BYTES`], a multipart upload above.
    async fn upload(&self, path: &Path, key: &Key, bytes: u64) -> Result<(), StoreError> {
        let local = |what: &'static str, error: std::io::Error| StoreError::Local {
            what,
            path: path.to_path_buf(),
            error,
        };
        if bytes <= MULTIPART_BYTES as u64 {
            let data = tokio::fs::read(path)
                .await
                .map_err(|e| local("reading", e))?;
            self.store
                .put(key, PutPayload::from(data))
                .await
                .map_err(|e| self.backend("write", key, e))?;
            return Ok(());
        }
        let mut upload = self
            .store
            .put_multipart(key)
            .await
            .map_err(|e| self.backend("write", key, e))?;
        let sent = async {
            let mut file = tokio::fs::File::open(path)
                .await
                .map_err(|e| local("reading", e))?;
            let mut in_flight: futures_util::stream::FuturesUnordered<object_store::UploadPart> =
                futures_util::stream::FuturesUnordered::new();
            loop {
                // Every part but the last is exactly MULTIPART_BYTES (S3's rule).
                let mut part = vec![0u8; MULTIPART_BYTES];
                let mut filled = 0;
                while filled < part.len() {
                    let n = tokio::io::AsyncReadExt::read(&mut file, &mut part[filled..])
                        .await
                        .map_err(|e| local("reading", e))?;
                    if n == 0 {
                        break;
                    }
                    filled += n;
                }
                if filled == 0 {
                    break;
                }
                part.truncate(filled);
                while in_flight.len() >= MULTIPART_PARALLEL {
                    if let Some(done) = in_flight.next().await {
                        done.map_err(|e| self.backend("write", key, e))?;
                    }
                }
                in_flight.push(upload.put_part(PutPayload::from(part)));
                if filled < MULTIPART_BYTES {
                    break;
                }
            }
            while let Some(done) = in_flight.next().await {
                done.map_err(|e| self.backend("write", key, e))?;
            }
            upload
                .complete()
                .await
                .map_err(|e| self.backend("write", key, e))
        }
        .await;
        match sent {
            Ok(_) => Ok(()),
            Err(err) => {
                // The parts sent so far are removed (an upload cancelled outright leaves them
                // to the bucket's lifecycle rule for incomplete multipart uploads).
                if let Err(abort) = upload.abort().await {
                    tracing::warn!(store = self.url, key = %key, error = %abort, "cannot abort a failed multipart upload");
                }
                Err(err)
            }
        }
    }

    /// Removes the name `id` (the content stays: other ids may name it). Removing a name that
    /// does not exist succeeds.
    ///
    /// # Errors
    /// The store fails.
    pub async fn remove_name(&self, id: &str) -> Result<(), StoreError> {
        let key = Self::name_key(id);
        match self.store.delete(&key).await {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(self.backend("delete", &key, e)),
        }
    }

    /// Removes the temporary files an interrupted fetch left in the cache.
    fn remove_temporaries(&self) {
        let dir = self.cache_dir.join("sha256");
        let Ok(entries) = std::fs::read_dir(&dir) else {
            return;
        };
        for entry in entries.flatten() {
            let name = entry.file_name();
            if name
                .to_str()
                .and_then(lumigraph_core::temp_target)
                .is_some()
            {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }
}

/// Whether the store refused the request's credentials: a 401 or 403 answer. `object_store`
/// types them for single-object requests; a listing's refusal comes as a generic error whose
/// message carries the status (its retry error type is not public).
fn is_refusal(error: &object_store::Error) -> bool {
    match error {
        object_store::Error::PermissionDenied { .. }
        | object_store::Error::Unauthenticated { .. } => true,
        error => {
            let text = error.to_string();
            text.contains("401 Unauthorized") || text.contains("403 Forbidden")
        }
    }
}

/// Deletes `path` on drop unless disarmed.
struct RemoveOnDrop(Option<PathBuf>);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        if let Some(path) = self.0.take() {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// Removes the least recently modified `*.lfa` files of `dir` not in `keep` until the folder's
/// `*.lfa` files take at most `limit` bytes (or only kept files are left). Returns the bytes
/// left.
fn evict(dir: &Path, limit: u64, keep: &HashSet<PathBuf>) -> std::io::Result<u64> {
    let mut files = Vec::new();
    let mut total = 0u64;
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        if path.extension().is_none_or(|e| e != "lfa") {
            continue;
        }
        let meta = match entry.metadata() {
            Ok(meta) => meta,
            // Removed meanwhile (another eviction, a delete).
            Err(err) if err.kind() == std::io::ErrorKind::NotFound => continue,
            Err(err) => return Err(err),
        };
        if !meta.is_file() {
            continue;
        }
        total += meta.len();
        let modified = meta.modified().unwrap_or(SystemTime::UNIX_EPOCH);
        files.push((modified, meta.len(), path));
    }
    files.sort();
    for (_, len, path) in files {
        if total <= limit {
            break;
        }
        if keep.contains(&path) {
            continue;
        }
        match std::fs::remove_file(&path) {
            Ok(()) => {
                total -= len;
                tracing::info!(path = %path.display(), bytes = len, "evicted from the store cache");
            }
            Err(err) if err.kind() == std::io::ErrorKind::NotFound => total -= len,
            Err(err) => return Err(err),
        }
    }
    Ok(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn store(dir: &Path, limit: u64) -> ContentStore {
        let url = format!("file://{}", dir.join("store").display());
        ContentStore::open(&url, dir.join("cache"), limit).expect("open")
    }

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, bytes).expect("write");
        path
    }

    #[tokio::test]
    async fn publish_then_fetch_verifies_and_names_are_create_only() {
        let dir = tempfile::tempdir().expect("tempdir");
        let s = store(dir.path(), 1 << 20);
        assert!(s.list_names().await.expect("list").is_empty());
        let a = write(dir.path(), "a.lfa", b"first asset");
        let record = s.publish("one", &a).await.expect("publish");
        assert_eq!(record.bytes, 11);
        assert_eq!(
            record.sha256,
            lumigraph_core::bake::sha256_hex(b"first asset")
        );
        // The same content under the same id again: idempotent.
        assert_eq!(s.publish("one", &a).await.expect("again"), record);
        // Other content under the same id: refused, and the name is unchanged.
        let b = write(dir.path(), "b.lfa", b"second asset");
        let err = s.publish("one", &b).await.expect_err("rebind");
        assert!(matches!(err, StoreError::NameTaken { .. }), "{err}");
        assert_eq!(
            s.resolve("one").await.expect("resolve"),
            Some(record.clone())
        );
        // The same content under a second id shares the object.
        assert_eq!(s.publish("two", &a).await.expect("alias"), record);
        assert_eq!(s.list_names().await.expect("list"), ["one", "two"]);
        let path = s
            .fetch("one", &record, &HashSet::new())
            .await
            .expect("fetch");
        assert_eq!(std::fs::read(&path).expect("read"), b"first asset");
        assert_eq!(path, s.cache_path(&record.sha256));
        s.remove_name("one").await.expect("remove");
        s.remove_name("one").await.expect("remove twice");
        assert_eq!(s.resolve("one").await.expect("resolve"), None);
        assert_eq!(s.list_names().await.expect("list"), ["two"]);
    }

    #[tokio::test]
    async fn a_corrupt_object_is_refused_and_not_cached() {
        let dir = tempfile::tempdir().expect("tempdir");
        let s = store(dir.path(), 1 << 20);
        let a = write(dir.path(), "a.lfa", b"original content");
        let record = s.publish("x", &a).await.expect("publish");
        let object = dir
            .path()
            .join("store/sha256")
            .join(format!("{}.lfa", record.sha256));
        for corrupt in [
            &b"original c0ntent"[..],
            b"original",
            b"original content and more",
        ] {
            std::fs::write(&object, corrupt).expect("corrupt");
            let err = s
                .fetch("x", &record, &HashSet::new())
                .await
                .expect_err("corrupt");
            assert!(matches!(err, StoreError::HashMismatch { .. }), "{err}");
            assert!(err.to_string().contains("corrupt object"), "{err}");
            assert!(!s.cache_path(&record.sha256).exists());
            let left: Vec<_> = std::fs::read_dir(dir.path().join("cache/sha256"))
                .expect("cache")
                .collect();
            assert!(left.is_empty(), "temporary files left: {left:?}");
        }
        // Publishing the content again replaces the damaged object.
        assert_eq!(s.publish("x", &a).await.expect("again"), record);
        let path = s.fetch("x", &record, &HashSet::new()).await.expect("fetch");
        assert_eq!(std::fs::read(path).expect("read"), b"original content");
    }

    #[tokio::test]
    async fn bad_records_are_typed_errors() {
        let dir = tempfile::tempdir().expect("tempdir");
        let s = store(dir.path(), 1 << 20);
        let names = dir.path().join("store/names");
        std::fs::create_dir_all(&names).expect("names");
        for (id, body) in [
            ("a", "not json".to_owned()),
            (
                "b",
                r#"{"sha256": "../../etc/passwd", "bytes": 3}"#.to_owned(),
            ),
            (
                "c",
                format!(r#"{{"sha256": "{}", "bytes": 3}}"#, "A".repeat(64)),
            ),
            ("d", "x".repeat(5000)),
        ] {
            std::fs::write(names.join(format!("{id}.json")), body).expect("write");
            let err = s.resolve(id).await.expect_err(id);
            assert!(matches!(err, StoreError::BadRecord { .. }), "{id}: {err}");
        }
        std::fs::write(names.join("bad id.json"), "{}").expect("write");
        std::fs::write(names.join("notes.txt"), "{}").expect("write");
        assert_eq!(s.list_names().await.expect("list"), ["a", "b", "c", "d"]);
    }

    #[tokio::test]
    async fn the_cache_keeps_its_bound_and_the_pinned_files() {
        let dir = tempfile::tempdir().expect("tempdir");
        let s = store(dir.path(), 100);
        let mut records = Vec::new();
        for i in 0..4u8 {
            let a = write(dir.path(), &format!("{i}.lfa"), &[i; 40]);
            records.push(s.publish(&format!("a{i}"), &a).await.expect("publish"));
        }
        let pinned: HashSet<PathBuf> = [s.cache_path(&records[0].sha256)].into();
        for (i, record) in records.iter().enumerate() {
            s.fetch(&format!("a{i}"), record, &pinned)
                .await
                .expect("fetch");
            // Distinct modification times order the eviction.
            std::thread::sleep(Duration::from_millis(20));
        }
        // 4 × 40 bytes under a bound of 100: the oldest unpinned (a1, then a2) went.
        let cached: Vec<bool> = records
            .iter()
            .map(|r| s.cache_path(&r.sha256).exists())
            .collect();
        assert_eq!(cached, [true, false, false, true]);
        let too_big = write(dir.path(), "big.lfa", &[9; 101]);
        let record = s.publish("big", &too_big).await.expect("publish");
        let err = s.fetch("big", &record, &pinned).await.expect_err("too big");
        assert!(matches!(err, StoreError::TooLarge { .. }), "{err}");
    }

    #[tokio::test]
    async fn large_files_go_up_in_parts_and_a_corrupt_object_is_replaced() {
        let dir = tempfile::tempdir().expect("tempdir");
        let s = store(dir.path(), 1 << 30);
        // Three parts, the last one short; bytes that differ from part to part.
        let data: Vec<u8> = (0..2 * MULTIPART_BYTES + 12_345)
            .map(|i| (i as u32).wrapping_mul(2_654_435_761).to_le_bytes()[3])
            .collect();
        let big = write(dir.path(), "big.lfa", &data);
        let record = s.publish("big", &big).await.expect("publish");
        assert_eq!(record.bytes, data.len() as u64);
        assert_eq!(record.sha256, lumigraph_core::bake::sha256_hex(&data));
        let object = dir
            .path()
            .join("store/sha256")
            .join(format!("{}.lfa", record.sha256));
        assert!(std::fs::read(&object).expect("object") == data);
        // Truncated in the store: a fetch refuses it, publishing again replaces it.
        std::fs::write(&object, &data[..1000]).expect("truncate");
        let err = s
            .fetch("big", &record, &HashSet::new())
            .await
            .expect_err("short");
        assert!(matches!(err, StoreError::HashMismatch { .. }), "{err}");
        assert_eq!(s.publish("big", &big).await.expect("again"), record);
        let path = s
            .fetch("big", &record, &HashSet::new())
            .await
            .expect("fetch");
        assert!(std::fs::read(path).expect("cached") == data);
    }

    #[test]
    fn bad_urls_are_config_errors() {
        let dir = tempfile::tempdir().expect("tempdir");
        for url in [
            "",
            "relative/path",
            "file://relative",
            "s3://",
            "gs://bucket",
            "http://x",
        ] {
            let err = ContentStore::open(url, dir.path().join("cache"), 1).expect_err(url);
            assert!(matches!(err, StoreError::Config { .. }), "{url}: {err}");
        }
    }
}
