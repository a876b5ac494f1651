//! LAZ decompression through the `laz` crate, exposed to C++ (see
//! include/surfcast_laz.h). Panics never cross the boundary: every entry
//! point catches them and reports an error instead.

use std::ffi::CStr;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::os::raw::{c_char, c_int};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Arc, Mutex};

use laz::laszip::ChunkTable;
use laz::{LasZipDecompressor, LazItemType, LazVlr, ParLasZipDecompressor};

enum Decompressor {
    Sequential(LasZipDecompressor<'static, BufReader<File>>),
    Parallel(ParLasZipDecompressor<BufReader<File>>, Arc<rayon::ThreadPool>),
}

// One decode pool for every reader: a build that reads thousands of files, or
// opens several at once, keeps one set of threads (a pool per reader once made
// 8,469 threads for 4,234 files). Replaced when a caller asks for another size;
// readers keep the pool they were given.
static POOL: Mutex<Option<Arc<rayon::ThreadPool>>> = Mutex::new(None);

fn shared_pool(threads: usize) -> Result<Arc<rayon::ThreadPool>, String> {
    let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(p) = pool.as_ref() {
        if p.current_num_threads() == threads {
            return Ok(Arc::clone(p));
        }
    }
    let p = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("laz-decode-{}", i))
            .build()
            .map_err(|e| format!("thread pool: {}", e))?,
    );
    *pool = Some(Arc::clone(&p));
    Ok(p)
}

pub struct ScLazReader {
    decompressor: Decompressor,
    point_size: u64,
    chunk_size: u64,
}

fn write_err(err: *mut c_char, err_len: usize, message: &str) {
    if err.is_null() || err_len == 0 {
        return;
    }
    let bytes = message.as_bytes();
    let n = bytes.len().min(err_len - 1);
    // SAFETY: the caller provides err_len writable bytes at err.
    unsafe {
        std::ptr::copy_nonoverlapping(bytes.as_ptr(), err as *mut u8, n);
        *err.add(n) = 0;
    }
}

fn panic_message(p: Box<dyn std::any::Any + Send>) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        s.to_string()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic".to_string()
    }
}

fn read_u64_at(f: &mut File, at: u64) -> Result<u64, String> {
    let mut b = [0u8; 8];
    f.seek(SeekFrom::Start(at)).and_then(|_| f.read_exact(&mut b)).map_err(|e| format!("cannot read at byte {}: {}", at, e))?;
    Ok(u64::from_le_bytes(b))
}

// The chunk table's entry count, checked before the `laz` crate sizes a
// vector by it (a crafted count made it allocate 37 GB: fuzz_read_laz). The
// table's offset is the first 8 bytes of the point data (or, when those are
// -1, the file's last 8 bytes); the table starts with a u32 version and the
// u32 count. Every chunk holds at least one point, and one byte of the file.
fn check_chunk_count(path: &str, data_offset: u64, point_count: u64, chunk_size: u64) -> Result<(), String> {
    let mut f = File::open(path).map_err(|e| format!("cannot open: {}", e))?;
    let size = f.metadata().map_err(|e| format!("cannot stat: {}", e))?.len();
    let mut table = read_u64_at(&mut f, data_offset)?;
    if table == u64::MAX && size >= 8 {
        table = read_u64_at(&mut f, size - 8)?;
    }
    if table < data_offset.saturating_add(8) || table.saturating_add(8) > size {
        return Err(format!("the chunk table offset {} lies outside the point data (file of {} bytes)", table, size));
    }
    let count = read_u64_at(&mut f, table)? >> 32;
    let most = if chunk_size > 0 { point_count / chunk_size + 1 } else { point_count.max(1) }.min(size);
    if count > most {
        return Err(format!("the chunk table claims {} chunks; {} points in a file of {} bytes allow at most {}",
                           count, point_count, size, most));
    }
    Ok(())
}

// Layered chunks (LAS 1.4 point formats 6-10) start with the first point raw,
// a u32 point count, then a u32 byte size per layer of every item; the `laz`
// crate sizes a buffer by each before it reads it (4 GB from a 1 KB file:
// fuzz_read_laz). The layers must fit in the chunk's bytes from the chunk table.
fn check_layer_sizes(path: &str, data_offset: u64, vlr: &LazVlr, table: &ChunkTable) -> Result<(), String> {
    let mut layers = 0u64;
    for item in vlr.items() {
        layers += match item.item_type() {
            LazItemType::Point14 => 9,
            LazItemType::RGB14 | LazItemType::WavePacket14 => 1,
            LazItemType::RGBNIR14 => 2,
            LazItemType::Byte14(n) => u64::from(n),
            _ => return Ok(()),  // not layered (LAS 1.0-1.3 formats): no sizes ahead of the data
        };
    }
    let mut f = File::open(path).map_err(|e| format!("cannot open: {}", e))?;
    let mut at = data_offset + 8;  // past the chunk table's offset
    for (k, chunk) in table.as_ref().iter().enumerate() {
        let head = vlr.items_size() + 4;
        let mut sizes = vec![0u8; usize::try_from(4 * layers).map_err(|_| "too many layers".to_string())?];
        f.seek(SeekFrom::Start(at + head)).and_then(|_| f.read_exact(&mut sizes))
            .map_err(|e| format!("chunk {}: cannot read its layer sizes: {}", k, e))?;
        let total: u64 = sizes.chunks(4).map(|b| u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))).sum();
        if head + 4 * layers + total > chunk.byte_count {
            return Err(format!("chunk {}: its layers claim {} bytes, the chunk table gives the chunk {}", k,
                               head + 4 * layers + total, chunk.byte_count));
        }
        at += chunk.byte_count;
    }
    Ok(())
}

fn open(path: &str, data_offset: u64, vlr: &[u8], point_count: u64, threads: usize) -> Result<ScLazReader, String> {
    let vlr = LazVlr::from_buffer(vlr).map_err(|e| format!("LASzip VLR: {}", e))?;
    let point_size = vlr.items_size();
    let chunk_size = if vlr.uses_variable_size_chunks() { 0 } else { u64::from(vlr.chunk_size()) };
    let open_at_data = || -> Result<BufReader<File>, String> {
        let mut f = BufReader::new(File::open(path).map_err(|e| format!("cannot open: {}", e))?);
        f.seek(SeekFrom::Start(data_offset)).map_err(|e| format!("cannot seek to the point data: {}", e))?;
        Ok(f)
    };

    // The chunk table (at the end of the file) says how many points there are:
    // a truncated file or a wrong header count fails here, before any work.
    check_chunk_count(path, data_offset, point_count, chunk_size)?;
    let chunks = match ChunkTable::read_from(open_at_data()?, &vlr) {
        Ok(table) => {
            check_layer_sizes(path, data_offset, &vlr, &table)?;
            let chunks = table.len() as u64;
            if chunk_size == 0 {
                let total: u64 = table.as_ref().iter().map(|e| e.point_count).sum();
                if total != point_count {
                    return Err(format!("header declares {} points, the chunk table holds {}", point_count, total));
                }
            } else if point_count > chunks * chunk_size || (chunks > 0 && point_count <= (chunks - 1) * chunk_size) {
                return Err(format!(
                    "header declares {} points, the chunk table has {} chunks of {} points",
                    point_count, chunks, chunk_size
                ));
            }
            chunks
        }
        Err(e) => return Err(format!("cannot read the chunk table (truncated file?): {}", e)),
    };

    // Chunks are the unit of parallel decoding: a file of one chunk (small
    // tiles, thousands per scan) decodes on the caller's thread.
    let decompressor = if threads > 1 && chunks > 1 {
        let pool = shared_pool(threads)?;
        let d = ParLasZipDecompressor::new(open_at_data()?, vlr).map_err(|e| format!("{}", e))?;
        Decompressor::Parallel(d, pool)
    } else {
        let d = LasZipDecompressor::new(open_at_data()?, vlr).map_err(|e| format!("{}", e))?;
        Decompressor::Sequential(d)
    };
    Ok(ScLazReader { decompressor, point_size, chunk_size })
}

#[no_mangle]
pub extern "C" fn sc_laz_open(
    path: *const c_char,
    data_offset: u64,
    vlr: *const u8,
    vlr_len: usize,
    point_count: u64,
    threads: c_int,
    err: *mut c_char,
    err_len: usize,
) -> *mut ScLazReader {
    if path.is_null() || vlr.is_null() {
        write_err(err, err_len, "null argument");
        return std::ptr::null_mut();
    }
    // SAFETY: the caller passes a NUL-terminated path and vlr_len readable bytes.
    let path = unsafe { CStr::from_ptr(path) }.to_string_lossy().into_owned();
    let vlr = unsafe { std::slice::from_raw_parts(vlr, vlr_len) };
    let threads = threads.max(1) as usize;
    match catch_unwind(|| open(&path, data_offset, vlr, point_count, threads)) {
        Ok(Ok(reader)) => Box::into_raw(Box::new(reader)),
        Ok(Err(message)) => {
            write_err(err, err_len, &message);
            std::ptr::null_mut()
        }
        Err(p) => {
            write_err(err, err_len, &format!("LAZ decoder panicked: {}", panic_message(p)));
            std::ptr::null_mut()
        }
    }
}

#[no_mangle]
pub extern "C" fn sc_laz_point_size(reader: *const ScLazReader) -> u64 {
    // SAFETY: reader comes from sc_laz_open.
    unsafe { reader.as_ref() }.map_or(0, |r| r.point_size)
}

#[no_mangle]
pub extern "C" fn sc_laz_chunk_size(reader: *const ScLazReader) -> u64 {
    // SAFETY: reader comes from sc_laz_open.
    unsafe { reader.as_ref() }.map_or(0, |r| r.chunk_size)
}

#[no_mangle]
pub extern "C" fn sc_laz_read(reader: *mut ScLazReader, out: *mut u8, points: u64, err: *mut c_char, err_len: usize) -> c_int {
    // SAFETY: reader comes from sc_laz_open; out has points * point_size bytes.
    let reader = match unsafe { reader.as_mut() } {
        Some(r) => r,
        None => {
            write_err(err, err_len, "null reader");
            return -1;
        }
    };
    let len = (points * reader.point_size) as usize;
    let out = unsafe { std::slice::from_raw_parts_mut(out, len) };
    let result = catch_unwind(AssertUnwindSafe(|| match &mut reader.decompressor {
        Decompressor::Sequential(d) => d.decompress_many(out).map_err(|e| format!("{}", e)),
        Decompressor::Parallel(d, pool) => pool.install(|| d.decompress_many(out)).map_err(|e| format!("{}", e)),
    }));
    match result {
        Ok(Ok(())) => 0,
        Ok(Err(message)) => {
            write_err(err, err_len, &message);
            -1
        }
        Err(p) => {
            write_err(err, err_len, &format!("LAZ decoder panicked: {}", panic_message(p)));
            -1
        }
    }
}

#[no_mangle]
pub extern "C" fn sc_laz_close(reader: *mut ScLazReader) {
    if !reader.is_null() {
        // SAFETY: reader comes from sc_laz_open and is closed once.
        drop(unsafe { Box::from_raw(reader) });
    }
}
