//! The persistent pipeline cache: a `VkPipelineCache` loaded from the user's cache directory when
//! the device opens and saved back when it closes, so a driver that stores compiled code in it
//! builds a pipeline once per machine instead of once per process.
//!
//! Where: `$SCATTERLAB_CACHE_DIR`, else `$XDG_CACHE_HOME/scatterlab`, else
//! `$HOME/.cache/scatterlab`; `--no-cache` (or `SCATTERLAB_CACHE_DIR=off`) turns it off. One file
//! per device and driver: `pipelines-<vendor>-<device>-<driver version>-<pipelineCacheUUID>.bin`.
//!
//! The file is the driver's cache data wrapped in an envelope of ours: a magic, the payload's
//! length and its SHA-256. On load the envelope and the driver's own header (vendor, device,
//! pipelineCacheUUID, Vulkan spec "Pipeline Cache" header version one) are checked before the
//! driver ever sees the bytes: a truncated or corrupt file, or one another device or driver wrote,
//! is ignored with one warning line and rewritten at exit, never handed to the driver (a driver
//! is not required to survive garbage). Saving writes a temporary sibling and renames it over the
//! file (atomic on POSIX), after merging in what another process saved since this one loaded,
//! so two processes sharing the file both succeed and the file is always one whole cache.
//!
//! What drivers do with it (measured, docs/decisions.md): lavapipe (Mesa 22.3) returns only the
//! 32-byte header, so its pipelines are compiled in every process whatever we do (Mesa keeps
//! llvmpipe's machine code in its own disk cache, `~/.cache/mesa_shader_cache`, which it uses
//! without us); NVIDIA's driver stores its compiled pipelines in it (and keeps a disk cache of
//! its own as well).

use std::path::{Path, PathBuf};

use ash::vk;
use sha2::{Digest, Sha256};

use super::error::VkContext;

/// Environment variable naming the cache directory (`off` or `0` turns the cache off).
pub const ENV_CACHE_DIR: &str = "SCATTERLAB_CACHE_DIR";

const MAGIC: &[u8; 8] = b"SLPCACHE";
const FORMAT: u32 = 1;
/// magic, format, reserved, payload length, SHA-256.
const ENVELOPE: usize = 8 + 4 + 4 + 8 + 32;
/// The Vulkan pipeline cache header, version one: size, version, vendor, device, UUID.
const VK_HEADER: usize = 32;

/// The cache directory from the environment (see the module doc); `None` when it is turned off
/// or no home directory is known.
pub fn default_cache_dir() -> Option<PathBuf> {
    let nonempty = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    if let Some(d) = nonempty(ENV_CACHE_DIR) {
        if d == "off" || d == "0" {
            return None;
        }
        return Some(PathBuf::from(d));
    }
    if let Some(x) = nonempty("XDG_CACHE_HOME") {
        return Some(PathBuf::from(x).join("scatterlab"));
    }
    nonempty("HOME").map(|h| PathBuf::from(h).join(".cache").join("scatterlab"))
}

/// What identifies the device and driver a cache belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CacheIdentity {
    pub vendor_id: u32,
    pub device_id: u32,
    pub driver_version: u32,
    pub uuid: [u8; 16],
}

impl CacheIdentity {
    pub fn of(props: &vk::PhysicalDeviceProperties) -> CacheIdentity {
        CacheIdentity {
            vendor_id: props.vendor_id,
            device_id: props.device_id,
            driver_version: props.driver_version,
            uuid: props.pipeline_cache_uuid,
        }
    }

    pub fn file_name(&self) -> String {
        let uuid: String = self.uuid.iter().map(|b| format!("{b:02x}")).collect();
        format!("pipelines-{:04x}-{:04x}-{:08x}-{uuid}.bin", self.vendor_id, self.device_id, self.driver_version)
    }
}

/// How the cache file was found when the device opened (recorded in every render's JSON).
#[derive(Clone, Debug, serde::Serialize)]
pub struct PipelineCacheStatus {
    /// The file, or `None` where the cache is off.
    pub path: Option<PathBuf>,
    /// `off`, `empty` (no file yet), `loaded`, or `ignored` (with a warning).
    pub state: &'static str,
    /// Bytes of driver data loaded.
    pub loaded_bytes: u64,
    /// Bytes of driver data the device held at the last save (0 before one).
    pub saved_bytes: u64,
    /// The warning printed when the file was ignored or could not be written.
    pub warning: Option<String>,
}

/// The payload of a cache file, or why it is unusable. `Ok(None)`: no file.
pub(crate) fn read_payload(path: &Path, id: &CacheIdentity) -> Result<Option<Vec<u8>>, String> {
    // No directory yet (or something else in its place): nothing to load; saving says why it
    // cannot write, once.
    if !path.parent().is_some_and(|d| d.is_dir()) {
        return Ok(None);
    }
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(format!("cannot be read ({e})")),
    };
    unwrap_envelope(&bytes, id).map(Some)
}

/// Check an envelope and the driver header inside it; the driver's bytes when both hold.
pub(crate) fn unwrap_envelope(bytes: &[u8], id: &CacheIdentity) -> Result<Vec<u8>, String> {
    if bytes.len() < ENVELOPE || &bytes[..8] != MAGIC {
        return Err("is not a scatterlab pipeline cache (bad magic or truncated)".into());
    }
    let u32_at = |b: &[u8], o: usize| u32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"));
    let format = u32_at(bytes, 8);
    if format != FORMAT {
        return Err(format!("has envelope format {format}, this build reads {FORMAT}"));
    }
    let len = u64::from_le_bytes(bytes[16..24].try_into().expect("8 bytes"));
    let payload = &bytes[ENVELOPE..];
    if payload.len() as u64 != len {
        return Err(format!("is truncated or padded ({} payload bytes, the header says {len})", payload.len()));
    }
    if Sha256::digest(payload).as_slice() != &bytes[24..56] {
        return Err("is corrupt (its checksum does not match)".into());
    }
    if payload.len() < VK_HEADER {
        return Err("holds no Vulkan pipeline cache header".into());
    }
    let (size, version) = (u32_at(payload, 0), u32_at(payload, 4));
    let (vendor, device) = (u32_at(payload, 8), u32_at(payload, 12));
    if (size as usize) < VK_HEADER || version != vk::PipelineCacheHeaderVersion::ONE.as_raw() as u32 {
        return Err(format!("has an unknown Vulkan cache header (size {size}, version {version})"));
    }
    if vendor != id.vendor_id || device != id.device_id || payload[16..32] != id.uuid {
        return Err(format!(
            "was written by another device or driver (vendor {vendor:#06x}, device {device:#06x}; this one is \
             {:#06x}, {:#06x}, or another pipelineCacheUUID)",
            id.vendor_id, id.device_id
        ));
    }
    Ok(payload.to_vec())
}

/// The file's bytes for `payload`.
pub(crate) fn envelope(payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(ENVELOPE + payload.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(Sha256::digest(payload).as_slice());
    out.extend_from_slice(payload);
    out
}

/// Write `bytes` to `path` through a temporary sibling renamed over it: a reader sees the old
/// file or the new one, never a part.
fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let mut tmp = tempfile::Builder::new().prefix(".pipelines-").suffix(".tmp").tempfile_in(dir)?;
    tmp.write_all(bytes)?;
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

/// The device's pipeline cache and the file it came from and goes back to.
pub(crate) struct DiskCache {
    pub cache: vk::PipelineCache,
    path: Option<PathBuf>,
    id: CacheIdentity,
    /// SHA-256 of the driver data loaded (or of nothing).
    loaded: [u8; 32],
    /// A save failed: not tried again (one warning per process).
    failed: bool,
    pub status: PipelineCacheStatus,
}

fn warn(path: &Path, what: &str) -> String {
    format!("pipeline cache {}: {what}", path.display())
}

impl DiskCache {
    /// Open the cache for this device from `dir` (`None`: an in-memory cache only). Returns the
    /// cache and at most one warning.
    pub fn open(
        device: &ash::Device,
        dir: Option<&Path>,
        id: CacheIdentity,
    ) -> super::Result<(DiskCache, Option<String>)> {
        let path = dir.map(|d| d.join(id.file_name()));
        let (payload, state, warning) = match &path {
            None => (Vec::new(), "off", None),
            Some(p) => match read_payload(p, &id) {
                Ok(None) => (Vec::new(), "empty", None),
                Ok(Some(b)) => (b, "loaded", None),
                Err(why) => (Vec::new(), "ignored", Some(warn(p, &format!("{why}; ignored, it will be rewritten")))),
            },
        };
        let info = vk::PipelineCacheCreateInfo::default().initial_data(&payload);
        let cache = match unsafe { device.create_pipeline_cache(&info, None) } {
            Ok(c) => c,
            // A driver may still refuse data that passed our checks: start empty rather than fail.
            Err(_) if !payload.is_empty() => {
                unsafe { device.create_pipeline_cache(&vk::PipelineCacheCreateInfo::default(), None) }
                    .vk("vkCreatePipelineCache")?
            }
            Err(e) => return Err(super::GpuError::Vk { call: "vkCreatePipelineCache", result: e }),
        };
        let loaded = Sha256::digest(&payload).into();
        let status = PipelineCacheStatus {
            path: path.clone(),
            state,
            loaded_bytes: payload.len() as u64,
            saved_bytes: 0,
            warning: warning.clone(),
        };
        Ok((DiskCache { cache, path, id, loaded, failed: false, status }, warning))
    }

    /// Save the cache if the driver added to it since it was loaded, merging what another
    /// process saved meanwhile. Returns a warning where it cannot be written.
    pub fn save(&mut self, device: &ash::Device) -> Option<String> {
        if self.failed {
            return None;
        }
        let path = self.path.clone()?;
        let data = unsafe { device.get_pipeline_cache_data(self.cache) }.ok()?;
        self.status.saved_bytes = data.len() as u64;
        let digest: [u8; 32] = Sha256::digest(&data).into();
        if digest == self.loaded {
            return None;
        }
        // Another process's save since this one loaded: merge it, so neither loses its pipelines.
        let mut data = data;
        if let Ok(Some(theirs)) = read_payload(&path, &self.id) {
            let theirs_digest: [u8; 32] = Sha256::digest(&theirs).into();
            if theirs_digest != self.loaded && theirs_digest != digest {
                let info = vk::PipelineCacheCreateInfo::default().initial_data(&theirs);
                if let Ok(other) = unsafe { device.create_pipeline_cache(&info, None) } {
                    if unsafe { device.merge_pipeline_caches(self.cache, &[other]) }.is_ok() {
                        if let Ok(merged) = unsafe { device.get_pipeline_cache_data(self.cache) } {
                            data = merged;
                        }
                    }
                    unsafe { device.destroy_pipeline_cache(other, None) };
                }
            }
        }
        match write_atomic(&path, &envelope(&data)) {
            Ok(()) => {
                self.loaded = Sha256::digest(&data).into();
                self.status.saved_bytes = data.len() as u64;
                None
            }
            Err(e) => {
                self.failed = true;
                let w = warn(
                    &path,
                    &format!(
                        "cannot be written ({e}); pipelines will be built again next time (set {ENV_CACHE_DIR} to a \
                     writable directory, or pass --no-cache)"
                    ),
                );
                self.status.warning = Some(w.clone());
                Some(w)
            }
        }
    }

    pub fn destroy(&mut self, device: &ash::Device) {
        unsafe { device.destroy_pipeline_cache(self.cache, None) };
        self.cache = vk::PipelineCache::null();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id() -> CacheIdentity {
        CacheIdentity { vendor_id: 0x10de, device_id: 0x2335, driver_version: 7, uuid: [3; 16] }
    }

    fn payload(id: &CacheIdentity, body: &[u8]) -> Vec<u8> {
        let mut p = Vec::new();
        p.extend_from_slice(&32u32.to_le_bytes());
        p.extend_from_slice(&1u32.to_le_bytes());
        p.extend_from_slice(&id.vendor_id.to_le_bytes());
        p.extend_from_slice(&id.device_id.to_le_bytes());
        p.extend_from_slice(&id.uuid);
        p.extend_from_slice(body);
        p
    }

    #[test]
    fn an_envelope_round_trips_and_every_damage_is_named() {
        let id = id();
        let p = payload(&id, b"compiled code");
        let file = envelope(&p);
        assert_eq!(unwrap_envelope(&file, &id).unwrap(), p);
        // Truncated anywhere: refused.
        for cut in [0, 7, ENVELOPE - 1, file.len() - 1] {
            assert!(unwrap_envelope(&file[..cut], &id).is_err(), "cut at {cut}");
        }
        // One flipped bit in the payload: the checksum.
        let mut bad = file.clone();
        *bad.last_mut().unwrap() ^= 1;
        assert!(unwrap_envelope(&bad, &id).unwrap_err().contains("checksum"));
        // Another device's cache (its header), with a valid envelope.
        let other = CacheIdentity { device_id: 0x2330, ..id };
        let foreign = envelope(&payload(&other, b"x"));
        assert!(unwrap_envelope(&foreign, &id).unwrap_err().contains("another device"));
        let mut uuid = id;
        uuid.uuid[0] = 9;
        assert!(unwrap_envelope(&envelope(&payload(&uuid, b"x")), &id).unwrap_err().contains("another device"));
        // No Vulkan header at all.
        assert!(unwrap_envelope(&envelope(b"short"), &id).unwrap_err().contains("header"));
    }

    #[test]
    fn the_file_name_carries_device_driver_and_uuid() {
        let n = id().file_name();
        assert_eq!(n, "pipelines-10de-2335-00000007-03030303030303030303030303030303.bin");
    }
}
