//! The crate's own pipeline-cache file ([`ContextDesc::pipeline_cache`](super::ContextDesc::pipeline_cache)):
//! `vkGetPipelineCacheData`'s bytes behind a header of the crate that names the device and driver they came from,
//! so that a file of another machine, driver version or GPU is never handed to the driver.
//!
//! Layout (little-endian), 64 bytes of header then the data:
//!
//! | bytes  | field                                                   |
//! |--------|---------------------------------------------------------|
//! | 0..8   | magic `MCHPCACH`                                        |
//! | 8..12  | format version (1)                                      |
//! | 12..16 | zero                                                    |
//! | 16..32 | `deviceUUID` (`VkPhysicalDeviceIDProperties`)           |
//! | 32..48 | `driverUUID`                                            |
//! | 48..56 | data length in bytes                                    |
//! | 56..64 | FNV-1a 64 of the data                                   |
//!
//! The data must also start with a `VkPipelineCacheHeaderVersionOne` of this device (vendor id, device id,
//! `pipelineCacheUUID`).

use ash::vk;
use std::io::Write as _;
use std::path::Path;

const MAGIC: [u8; 8] = *b"MCHPCACH";
const FORMAT: u32 = 1;
const HEADER: usize = 64;
/// `sizeof(VkPipelineCacheHeaderVersionOne)`.
const VK_HEADER: usize = 16 + vk::UUID_SIZE;

/// What a cache file must have been written for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CacheKey {
    /// `deviceUUID`.
    pub device_uuid: [u8; vk::UUID_SIZE],
    /// `driverUUID`.
    pub driver_uuid: [u8; vk::UUID_SIZE],
    /// `VkPhysicalDeviceProperties::vendorID`.
    pub vendor_id: u32,
    /// `VkPhysicalDeviceProperties::deviceID`.
    pub device_id: u32,
    /// `pipelineCacheUUID`.
    pub pipeline_cache_uuid: [u8; vk::UUID_SIZE],
}

fn fnv1a64(data: &[u8]) -> u64 {
    data.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3))
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    let mut w = [0u8; 4];
    w.copy_from_slice(&b[at..at + 4]);
    u32::from_le_bytes(w)
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut w = [0u8; 8];
    w.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(w)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The file holding `data` for the device of `key`.
pub(crate) fn encode(key: &CacheKey, data: &[u8]) -> Vec<u8> {
    let mut f = Vec::with_capacity(HEADER + data.len());
    f.extend_from_slice(&MAGIC);
    f.extend_from_slice(&FORMAT.to_le_bytes());
    f.extend_from_slice(&0u32.to_le_bytes());
    f.extend_from_slice(&key.device_uuid);
    f.extend_from_slice(&key.driver_uuid);
    f.extend_from_slice(&(data.len() as u64).to_le_bytes());
    f.extend_from_slice(&fnv1a64(data).to_le_bytes());
    f.extend_from_slice(data);
    f
}

/// The Vulkan data of a file written by [`encode`] for the device of `key`, or why it cannot be used.
pub(crate) fn decode<'a>(key: &CacheKey, file: &'a [u8]) -> Result<&'a [u8], String> {
    if file.len() < HEADER || file[..8] != MAGIC {
        return Err(format!("not a meshchar pipeline cache ({} bytes, no meshchar header)", file.len()));
    }
    let format = u32_at(file, 8);
    if format != FORMAT {
        return Err(format!("format version {format}, expected {FORMAT}"));
    }
    let (device, driver) = (&file[16..32], &file[32..48]);
    if device != key.device_uuid || driver != key.driver_uuid {
        return Err(format!(
            "written for another device or driver (device UUID {}, driver UUID {}; this one has {} and {})",
            hex(device),
            hex(driver),
            hex(&key.device_uuid),
            hex(&key.driver_uuid)
        ));
    }
    let data = &file[HEADER..];
    let len = u64_at(file, 48);
    if len != data.len() as u64 {
        return Err(format!("truncated or padded: header says {len} bytes of data, the file has {}", data.len()));
    }
    if u64_at(file, 56) != fnv1a64(data) {
        return Err("corrupted: the checksum of its data does not match".into());
    }
    if data.len() < VK_HEADER {
        return Err(format!("its Vulkan cache header is short ({} bytes)", data.len()));
    }
    let (size, version) = (u32_at(data, 0) as usize, u32_at(data, 4));
    let (vendor, device_id, uuid) = (u32_at(data, 8), u32_at(data, 12), &data[16..VK_HEADER]);
    if size < VK_HEADER || size > data.len() || version != vk::PipelineCacheHeaderVersion::ONE.as_raw() as u32 {
        return Err(format!("invalid Vulkan cache header (size {size}, version {version})"));
    }
    if vendor != key.vendor_id || device_id != key.device_id || uuid != key.pipeline_cache_uuid {
        return Err(format!(
            "its Vulkan cache header is for vendor {vendor:#x} device {device_id:#x} pipelineCacheUUID {}; this \
             device is vendor {:#x} device {:#x} pipelineCacheUUID {}",
            hex(uuid),
            key.vendor_id,
            key.device_id,
            hex(&key.pipeline_cache_uuid)
        ));
    }
    Ok(data)
}

/// The Vulkan data of the cache file at `path` for the device of `key`: empty when the file does not exist, an
/// error (the reason, as text) when it cannot be read or used.
pub(crate) fn load(path: &Path, key: &CacheKey) -> Result<Vec<u8>, String> {
    match std::fs::read(path) {
        Ok(file) => decode(key, &file).map(<[u8]>::to_vec),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(e) => Err(format!("cannot be read ({e})")),
    }
}

/// Writes `bytes` to `path` atomically: into a temporary file next to it, flushed to disk, then renamed over it
/// (readers see the old file or the new one, never a part). Creates the directory if needed.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let name = path.file_name().ok_or_else(|| std::io::Error::other("the path names no file"))?;
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    let mut tmp_name = name.to_os_string();
    tmp_name.push(format!(".tmp-{}-{nanos}", std::process::id()));
    let tmp = dir.join(tmp_name);
    let written = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key() -> CacheKey {
        CacheKey {
            device_uuid: [1; 16],
            driver_uuid: [2; 16],
            vendor_id: 0x10005,
            device_id: 7,
            pipeline_cache_uuid: [3; 16],
        }
    }

    fn vk_data(k: &CacheKey, extra: &[u8]) -> Vec<u8> {
        let mut d = Vec::new();
        d.extend_from_slice(&(VK_HEADER as u32).to_le_bytes());
        d.extend_from_slice(&1u32.to_le_bytes());
        d.extend_from_slice(&k.vendor_id.to_le_bytes());
        d.extend_from_slice(&k.device_id.to_le_bytes());
        d.extend_from_slice(&k.pipeline_cache_uuid);
        d.extend_from_slice(extra);
        d
    }

    #[test]
    fn round_trip_and_every_rejection() {
        let k = key();
        let data = vk_data(&k, b"pipelines");
        let file = encode(&k, &data);
        assert_eq!(decode(&k, &file), Ok(&data[..]));
        // Truncated, padded, corrupted.
        assert!(decode(&k, &file[..file.len() - 1]).is_err_and(|e| e.contains("truncated")));
        assert!(decode(&k, &file[..10]).is_err_and(|e| e.contains("not a meshchar")));
        let mut padded = file.clone();
        padded.push(0);
        assert!(decode(&k, &padded).is_err_and(|e| e.contains("truncated")));
        let mut bad = file.clone();
        *bad.last_mut().unwrap_or(&mut 0) ^= 1;
        assert!(decode(&k, &bad).is_err_and(|e| e.contains("corrupted")));
        // Another device, driver, or Vulkan header.
        let other = CacheKey { driver_uuid: [9; 16], ..k };
        assert!(decode(&other, &file).is_err_and(|e| e.contains("another device or driver")));
        let other = CacheKey { device_uuid: [9; 16], ..k };
        assert!(decode(&other, &file).is_err_and(|e| e.contains("another device or driver")));
        let other = CacheKey { pipeline_cache_uuid: [9; 16], ..k };
        assert!(decode(&other, &file).is_err_and(|e| e.contains("pipelineCacheUUID")));
        let other = CacheKey { device_id: 8, ..k };
        assert!(decode(&other, &file).is_err_and(|e| e.contains("Vulkan cache header")));
        assert!(decode(&k, &encode(&k, b"short")).is_err_and(|e| e.contains("short")));
        let mut v2 = data.clone();
        v2[4] = 2;
        assert!(decode(&k, &encode(&k, &v2)).is_err_and(|e| e.contains("invalid Vulkan cache header")));
        let mut other_format = file.clone();
        other_format[8] = 2;
        assert!(decode(&k, &other_format).is_err_and(|e| e.contains("format version 2")));
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temporary() {
        let dir = std::env::temp_dir().join(format!("meshchar-pcache-unit-{}", std::process::id()));
        let path = dir.join("sub").join("cache.bin");
        write_atomic(&path, b"one").expect("first write");
        write_atomic(&path, b"two").expect("second write");
        assert_eq!(std::fs::read(&path).ok().as_deref(), Some(&b"two"[..]));
        let names: Vec<_> = std::fs::read_dir(dir.join("sub")).map(|r| r.flatten().count()).into_iter().collect();
        assert_eq!(names, [1], "only the cache file is left");
        assert_eq!(load(&dir.join("missing.bin"), &key()), Ok(Vec::new()));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
