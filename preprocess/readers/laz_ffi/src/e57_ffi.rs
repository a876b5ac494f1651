//! E57 reading through the `e57` crate, exposed to C++ (see
//! include/surfcast_e57.h). Every scan (Data3D entry) of a file is read in
//! order with its pose applied, spherical coordinates converted, and
//! intensity and colour normalized by the scan's limits. Panics never cross
//! the boundary.

use std::io::{Read, Seek, SeekFrom};
use std::os::raw::{c_char, c_int, c_void};
use std::panic::{catch_unwind, AssertUnwindSafe};

use e57::{E57Reader, PointCloud, PointCloudReaderSimple, RecordDataType, RecordName};

use crate::{panic_message, seek_to, write_err, Input, ScReadAt};

/// One scan's description (include/surfcast_e57.h).
#[repr(C)]
pub struct ScE57Scan {
    pub points: u64,
    pub origin: [f64; 3],
    pub has_pose: u8,
    pub spherical: u8,
    pub cartesian: u8,
    pub color: u8,
    pub intensity: u8,
    pub row_column: u8,
    pub intensity_normalized: u8,
}

/// One point (include/surfcast_e57.h).
#[repr(C)]
pub struct ScE57Point {
    pub position: [f64; 3],
    pub intensity: f32,
    pub color: [f32; 3],
    pub row: i64,
    pub column: i64,
    pub scan: u32,
    pub valid: u8,
    pub pad: [u8; 3],
}

// E57 pages are 1 KiB, each read with a seek: the file is read through a
// window of WINDOW bytes, so a local file or a URL sees large reads.
const WINDOW: usize = 1 << 20;
// A quaternion whose squared norm is this far from 1 would scale its scan.
const QUATERNION_TOLERANCE: f64 = 1e-3;

struct Window {
    file: Input,
    buf: Vec<u8>,
    start: u64,
    pos: u64,
}

impl Read for Window {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        let end = self.start + self.buf.len() as u64;
        if self.pos < self.start || self.pos >= end {
            if self.pos >= self.file.size {
                return Ok(0);
            }
            let len = (self.file.size - self.pos).min(WINDOW as u64) as usize;
            self.buf.resize(len, 0);
            self.file.pos = self.pos;
            self.file.read_exact(&mut self.buf)?;
            self.start = self.pos;
        }
        let at = (self.pos - self.start) as usize;
        let n = out.len().min(self.buf.len() - at);
        out[..n].copy_from_slice(&self.buf[at..at + n]);
        self.pos += n as u64;
        Ok(n)
    }
}

impl Seek for Window {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        self.pos = seek_to(self.file.size, self.pos, to)?;
        Ok(self.pos)
    }
}

pub struct ScE57Reader {
    // Borrows *file: Drop ends it before it frees the reader.
    points: Option<PointCloudReaderSimple<'static, Window>>,
    file: *mut E57Reader<Window>,
    clouds: Vec<PointCloud>,
    images: u64,
    scan: usize,     // the scan `points` reads
    failed: Option<String>,
}

impl Drop for ScE57Reader {
    fn drop(&mut self) {
        self.points = None;
        // SAFETY: `file` comes from Box::into_raw in open(), and nothing borrows it now.
        drop(unsafe { Box::from_raw(self.file) });
    }
}

// "scan 2 ('Station 3')", as errors name a scan.
fn scan_name(clouds: &[PointCloud], scan: usize) -> String {
    match clouds.get(scan).and_then(|c| c.name.as_deref()) {
        Some(name) => format!("scan {} ('{}')", scan, name),
        None => format!("scan {}", scan),
    }
}

fn has(cloud: &PointCloud, name: RecordName) -> bool {
    cloud.prototype.iter().any(|r| r.name == name)
}

// The E57 header's XML length, checked against the file's size before the
// crate allocates that many bytes for it.
fn check_header(file: &mut Input) -> Result<(), String> {
    let mut header = [0u8; 48];
    file.pos = 0;
    if file.size < 48 || file.read_exact(&mut header).is_err() {
        return Err("not an E57 file (shorter than its 48-byte header)".to_string());
    }
    if &header[0..8] != b"ASTM-E57" {
        return Err("not an E57 file (no 'ASTM-E57' signature)".to_string());
    }
    let field = |at: usize| u64::from_le_bytes(header[at..at + 8].try_into().unwrap());
    let (physical_length, xml_length) = (field(16), field(32));
    if physical_length != file.size {
        return Err(format!("the header declares {} bytes, the file has {} (truncated?)", physical_length, file.size));
    }
    if xml_length > file.size {
        return Err(format!("the header declares {} bytes of XML in a file of {}", xml_length, file.size));
    }
    Ok(())
}

fn open(mut file: Input) -> Result<ScE57Reader, String> {
    check_header(&mut file)?;
    let window = Window { file, buf: Vec::new(), start: 0, pos: 0 };
    let reader = E57Reader::new(window).map_err(|e| format!("{}", e))?;
    let clouds = reader.pointclouds();
    let images = reader.images().len() as u64;
    for (k, c) in clouds.iter().enumerate() {
        let cartesian = has(c, RecordName::CartesianX) && has(c, RecordName::CartesianY) && has(c, RecordName::CartesianZ);
        let spherical = has(c, RecordName::SphericalRange) && has(c, RecordName::SphericalAzimuth) &&
                        has(c, RecordName::SphericalElevation);
        if !cartesian && !spherical {
            let fields: Vec<String> = c.prototype.iter().map(|r| match &r.name {
                RecordName::Unknown { namespace, name } if namespace.is_empty() => name.clone(),
                RecordName::Unknown { namespace, name } => format!("{}:{}", namespace, name),
                known => format!("{:?}", known),
            }).collect();
            return Err(format!("{}: neither cartesian nor spherical coordinates among its fields ({})", scan_name(&clouds, k),
                               fields.join(", ")));
        }
        if let Some(t) = &c.transform {
            let p = &t.translation;
            if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
                return Err(format!("{}: the pose's translation ({}, {}, {}) is not finite", scan_name(&clouds, k), p.x, p.y, p.z));
            }
            let q = &t.rotation;
            let norm = q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z;
            if !((norm - 1.0).abs() <= QUATERNION_TOLERANCE) {
                return Err(format!("{}: the pose's rotation quaternion ({}, {}, {}, {}) is not a unit quaternion",
                                   scan_name(&clouds, k), q.w, q.x, q.y, q.z));
            }
        }
    }
    let file = Box::into_raw(Box::new(reader));
    Ok(ScE57Reader { points: None, file, clouds, images, scan: 0, failed: None })
}

// Whether the scan's intensity has a range to normalize by: limits in the
// file, or an integer field's own bounds.
fn intensity_has_range(cloud: &PointCloud) -> bool {
    let limited = cloud.intensity_limits.as_ref().map_or(false, |l| l.intensity_min.is_some() && l.intensity_max.is_some());
    let bounded = cloud.prototype.iter().any(|r| {
        r.name == RecordName::Intensity &&
            matches!(r.data_type, RecordDataType::Integer { .. } | RecordDataType::ScaledInteger { .. } |
                                   RecordDataType::Single { min: Some(_), max: Some(_) } |
                                   RecordDataType::Double { min: Some(_), max: Some(_) })
    });
    limited || bounded
}

impl ScE57Reader {
    fn describe(&self, scan: usize) -> Option<ScE57Scan> {
        let c = self.clouds.get(scan)?;
        let t = c.transform.as_ref();
        let origin = t.map_or([0.0; 3], |t| [t.translation.x, t.translation.y, t.translation.z]);
        Some(ScE57Scan {
            points: c.records,
            origin,
            has_pose: t.is_some() as u8,
            spherical: has(c, RecordName::SphericalRange) as u8,
            cartesian: has(c, RecordName::CartesianX) as u8,
            color: c.has_color() as u8,
            intensity: c.has_intensity() as u8,
            row_column: c.has_row_column() as u8,
            intensity_normalized: intensity_has_range(c) as u8,
        })
    }

    // The next points, scan after scan, into `out`: how many (0: the end).
    fn read(&mut self, out: &mut [ScE57Point]) -> Result<usize, String> {
        let mut n = 0;
        while n < out.len() && self.scan < self.clouds.len() {
            // An empty scan's section is not read (some writers leave it unwritten).
            if self.points.is_none() && self.clouds[self.scan].records == 0 {
                self.scan += 1;
                continue;
            }
            if self.points.is_none() {
                // SAFETY: `file` lives until drop, after `points`; one reader borrows it at a time.
                let file: &'static mut E57Reader<Window> = unsafe { &mut *self.file };
                let cloud = &self.clouds[self.scan];
                let mut r = file.pointcloud_simple(cloud).map_err(|e| format!("{}: {}", scan_name(&self.clouds, self.scan), e))?;
                r.apply_pose(true);
                r.spherical_to_cartesian(true);
                r.intensity_to_color(false);
                r.normalize_color(true);
                r.normalize_intensity(intensity_has_range(cloud));
                self.points = Some(r);
            }
            let points = self.points.as_mut().unwrap();
            match points.next() {
                None => {
                    self.points = None;
                    self.scan += 1;
                }
                Some(Err(e)) => return Err(format!("{}: {}", scan_name(&self.clouds, self.scan), e)),
                Some(Ok(p)) => {
                    let o = &mut out[n];
                    o.valid = 0;
                    o.position = [f64::NAN; 3];
                    if let e57::CartesianCoordinate::Valid { x, y, z } = p.cartesian {
                        o.position = [x, y, z];
                        o.valid = 1;
                    }
                    o.intensity = p.intensity.unwrap_or(f32::NAN);
                    o.color = p.color.map_or([f32::NAN; 3], |c| [c.red, c.green, c.blue]);
                    o.row = p.row;
                    o.column = p.column;
                    o.scan = self.scan as u32;
                    o.pad = [0; 3];
                    n += 1;
                }
            }
        }
        Ok(n)
    }
}

#[no_mangle]
pub extern "C" fn sc_e57_open(file_size: u64, read_at: Option<ScReadAt>, ctx: *mut c_void, err: *mut c_char,
                              err_len: usize) -> *mut ScE57Reader {
    let read_at = match read_at {
        Some(f) => f,
        None => {
            write_err(err, err_len, "null argument");
            return std::ptr::null_mut();
        }
    };
    let file = Input { read_at, ctx, size: file_size, pos: 0 };
    match catch_unwind(AssertUnwindSafe(|| open(file))) {
        Ok(Ok(reader)) => Box::into_raw(Box::new(reader)),
        Ok(Err(message)) => {
            write_err(err, err_len, &message);
            std::ptr::null_mut()
        }
        Err(p) => {
            write_err(err, err_len, &format!("E57 reader panicked: {}", panic_message(p)));
            std::ptr::null_mut()
        }
    }
}

#[no_mangle]
pub extern "C" fn sc_e57_scan_count(reader: *const ScE57Reader) -> u64 {
    // SAFETY: reader comes from sc_e57_open.
    unsafe { reader.as_ref() }.map_or(0, |r| r.clouds.len() as u64)
}

#[no_mangle]
pub extern "C" fn sc_e57_image_count(reader: *const ScE57Reader) -> u64 {
    // SAFETY: reader comes from sc_e57_open.
    unsafe { reader.as_ref() }.map_or(0, |r| r.images)
}

#[no_mangle]
pub extern "C" fn sc_e57_scan(reader: *const ScE57Reader, scan: u64, out: *mut ScE57Scan, name: *mut c_char,
                              name_len: usize) -> c_int {
    // SAFETY: reader comes from sc_e57_open; out is writable.
    let reader = match unsafe { reader.as_ref() } {
        Some(r) if !out.is_null() => r,
        _ => return -1,
    };
    match reader.describe(scan as usize) {
        Some(d) => {
            unsafe { *out = d };
            write_err(name, name_len, &scan_name(&reader.clouds, scan as usize));
            0
        }
        None => -1,
    }
}

#[no_mangle]
pub extern "C" fn sc_e57_read(reader: *mut ScE57Reader, out: *mut ScE57Point, max: u64, err: *mut c_char,
                              err_len: usize) -> i64 {
    // SAFETY: reader comes from sc_e57_open; out has room for max points.
    let reader = match unsafe { reader.as_mut() } {
        Some(r) if !out.is_null() => r,
        _ => {
            write_err(err, err_len, "null argument");
            return -1;
        }
    };
    if let Some(e) = &reader.failed {
        write_err(err, err_len, e);
        return -1;
    }
    let out = unsafe { std::slice::from_raw_parts_mut(out, max as usize) };
    let result = match catch_unwind(AssertUnwindSafe(|| reader.read(out))) {
        Ok(r) => r,
        Err(p) => Err(format!("E57 reader panicked: {}", panic_message(p))),
    };
    match result {
        Ok(n) => n as i64,
        Err(message) => {
            // A reader that failed mid-scan may hold a broken state: it stays failed.
            reader.points = None;
            write_err(err, err_len, &message);
            reader.failed = Some(message);
            -1
        }
    }
}

#[no_mangle]
pub extern "C" fn sc_e57_close(reader: *mut ScE57Reader) {
    if !reader.is_null() {
        // SAFETY: reader comes from sc_e57_open and is closed once.
        drop(unsafe { Box::from_raw(reader) });
    }
}
