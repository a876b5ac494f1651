//! LAZ decompression through the `laz` crate, exposed to C++ (see
//! include/surfcast_laz.h). Panics never cross the boundary: every entry
//! point catches them and reports an error instead.

use std::io::{BufReader, Read, Seek, SeekFrom};
use std::os::raw::{c_char, c_int, c_void};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Arc, Mutex};

use laz::laszip::{ChunkTable, ChunkTableEntry};
use laz::{par_decompress, LasZipDecompressor, LazItemType, LazVlr};

mod e57_ffi;
mod laz_writer;

/// Reads up to `len` bytes at `offset` into `out`: the bytes read (fewer
/// only where the file ends), or -1.
pub type ScReadAt = extern "C" fn(ctx: *mut c_void, offset: u64, out: *mut u8, len: u64) -> i64;

// The file, read through the caller's function (a local file or a URL: the
// caller's input_file.h), at a position of its own.
struct Input {
    read_at: ScReadAt,
    ctx: *mut c_void,
    size: u64,
    pos: u64,
}

// SAFETY: the caller's function is called on the thread that calls
// sc_laz_open or sc_laz_read only (ChunkRange reads before it hands the pool
// the decoding), one call at a time for a reader; the `laz` crate asks for
// Sync of what it reads, and shares none of it across threads.
unsafe impl Send for Input {}
unsafe impl Sync for Input {}

impl Input {
    fn at(&self, pos: u64) -> Input {
        Input { read_at: self.read_at, ctx: self.ctx, size: self.size, pos }
    }
}

impl Read for Input {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = (self.read_at)(self.ctx, self.pos, buf.as_mut_ptr(), buf.len() as u64);
        if n < 0 {
            return Err(std::io::Error::new(std::io::ErrorKind::Other, format!("cannot read at byte {}", self.pos)));
        }
        self.pos += n as u64;
        Ok(n as usize)
    }
}

// Where a seek from `pos` in a file of `size` bytes lands.
fn seek_to(size: u64, pos: u64, to: SeekFrom) -> std::io::Result<u64> {
    let pos = match to {
        SeekFrom::Start(n) => Some(n),
        SeekFrom::End(d) => size.checked_add_signed(d),
        SeekFrom::Current(d) => pos.checked_add_signed(d),
    };
    pos.ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "seek before the file's start"))
}

impl Seek for Input {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        self.pos = seek_to(self.size, self.pos, to)?;
        Ok(self.pos)
    }
}

enum Decompressor {
    Sequential(LasZipDecompressor<'static, BufReader<Input>>),
    Range(ChunkRange),
    TableOnly,
}

// A run of whole chunks (the whole file, or a part of it split across
// processes), a batch of chunks at a time: their bytes read on the calling
// thread, decoded in parallel on the pool. The crate's own parallel reader
// reads its source on a pool thread, and its seek assumes that every chunk
// holds chunk_size points (point % count), which variable chunks (COPC) break.
struct ChunkRange {
    file: Input,
    vlr: LazVlr,
    chunks: Vec<ChunkTableEntry>, // the range's chunks, with their true point counts
    offsets: Vec<u64>,            // each one's first byte in the file
    next: usize,                  // the next chunk to decode
    rest: Vec<u8>,                // a chunk's decoded points not yet handed out, from `taken` on
    taken: usize,
    failed: Option<String>,       // a read or decode failed: every later read fails with it
    pool: Arc<rayon::ThreadPool>,
}

// The most decoded bytes one chunk of a range may hold, and the most bytes a
// chunk may take for them (compressed data can exceed the raw size a little):
// what a crafted chunk table can make a reader allocate.
const RANGE_CHUNK_BYTES: u64 = 256 << 20;
fn most_compressed(decoded: u64) -> u64 {
    decoded.saturating_mul(2).saturating_add(1 << 16)
}
// Decoded bytes per batch, at most (the C++ reader asks for 32 MiB at a time).
const RANGE_BATCH_BYTES: u64 = 32 << 20;

impl ChunkRange {
    // Whole chunks that fit in `out` are decoded straight into it; a chunk
    // that `out` cuts is decoded aside and handed out over several reads.
    fn read(&mut self, mut out: &mut [u8]) -> Result<(), String> {
        if let Some(e) = &self.failed {
            return Err(e.clone());
        }
        let point_size = self.vlr.items_size() as usize;
        while !out.is_empty() {
            if self.taken < self.rest.len() {
                let n = out.len().min(self.rest.len() - self.taken);
                out[..n].copy_from_slice(&self.rest[self.taken..self.taken + n]);
                self.taken += n;
                out = &mut out[n..];
                continue;
            }
            if self.next == self.chunks.len() {
                return Err("more points asked for than the range holds".to_string());
            }
            let (mut count, mut bytes) = (0, 0usize);
            for e in &self.chunks[self.next..] {
                let size = e.point_count as usize * point_size;
                if bytes + size > out.len() || (bytes + size) as u64 > RANGE_BATCH_BYTES {
                    break;
                }
                count += 1;
                bytes += size;
            }
            let result = if count > 0 {
                let (into, after) = out.split_at_mut(bytes);
                let r = self.decode(count, into);
                out = after;
                r
            } else {
                let mut rest = std::mem::take(&mut self.rest);
                rest.clear();
                rest.resize(self.chunks[self.next].point_count as usize * point_size, 0);
                let r = self.decode(1, &mut rest);
                self.rest = rest;
                self.taken = 0;
                r
            };
            if let Err(e) = result {
                self.failed = Some(e.clone());
                return Err(e);
            }
        }
        Ok(())
    }

    // Chunks next..next + count into `into`: their bytes read here, decoded on the pool.
    fn decode(&mut self, count: usize, into: &mut [u8]) -> Result<(), String> {
        let (first, last) = (self.next, self.next + count);
        let bytes: u64 = self.chunks[first..last].iter().map(|e| e.byte_count).sum();
        let mut compressed = vec![0u8; bytes as usize];
        self.file.seek(SeekFrom::Start(self.offsets[first])).and_then(|_| self.file.read_exact(&mut compressed))
            .map_err(|e| format!("chunk {}: cannot read its {} bytes at byte {}: {}", first, bytes, self.offsets[first], e))?;
        let (vlr, table) = (&self.vlr, &self.chunks[first..last]);
        self.pool.install(|| par_decompress(&compressed, into, vlr, table)).map_err(|e| format!("chunks {}-{}: {}", first, last - 1, e))?;
        self.next = last;
        Ok(())
    }
}

// One decode pool for every reader: a build that reads thousands of files, or
// opens several at once, keeps one set of threads (a pool per reader would make
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
    // Where each chunk starts: its first point, and its first byte in the
    // file (empty for point-wise compression, which has no chunks).
    starts: Vec<(u64, u64)>,
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

fn read_u64_at(f: &mut Input, at: u64) -> Result<u64, String> {
    let mut b = [0u8; 8];
    f.seek(SeekFrom::Start(at)).and_then(|_| f.read_exact(&mut b)).map_err(|e| format!("cannot read at byte {}: {}", at, e))?;
    Ok(u64::from_le_bytes(b))
}

// The chunk table's entry count, checked before the `laz` crate sizes a
// vector by it (a crafted count made it allocate 37 GB: fuzz_read_laz). The
// table's offset is the first 8 bytes of the point data (or, when those are
// -1, the file's last 8 bytes); the table starts with a u32 version and the
// u32 count. Every chunk holds at least one point, and one byte of the file.
// Returns the chunk table's offset.
fn check_chunk_count(file: &Input, data_offset: u64, point_count: u64, chunk_size: u64) -> Result<u64, String> {
    let mut f = file.at(0);
    let size = f.size;
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
    Ok(table)
}

// Layered chunks (LAS 1.4 point formats 6-10) start with the first point raw,
// a u32 point count, then a u32 byte size per layer of every item; the `laz`
// crate sizes a buffer by each before it reads it (4 GB from a 1 KB file:
// fuzz_read_laz). The layers must fit in the chunk's bytes from the chunk table.
fn check_layer_sizes(file: &Input, vlr: &LazVlr, chunks: &[ChunkTableEntry], offsets: &[u64], first_index: usize) -> Result<(), String> {
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
    let mut f = file.at(0);
    for (k, (chunk, &at)) in chunks.iter().zip(offsets).enumerate() {
        let k = first_index + k;
        let head = vlr.items_size() + 4;
        let mut sizes = vec![0u8; usize::try_from(4 * layers).map_err(|_| "too many layers".to_string())?];
        f.seek(SeekFrom::Start(at + head)).and_then(|_| f.read_exact(&mut sizes))
            .map_err(|e| format!("chunk {}: cannot read its layer sizes: {}", k, e))?;
        let total: u64 = sizes.chunks(4).map(|b| u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))).sum();
        if head + 4 * layers + total > chunk.byte_count {
            return Err(format!("chunk {}: its layers claim {} bytes, the chunk table gives the chunk {}", k,
                               head + 4 * layers + total, chunk.byte_count));
        }
    }
    Ok(())
}

// `table_only`: the chunk table (sc_laz_chunk_*), no points.
#[allow(clippy::too_many_arguments)]
fn open(file: Input, data_offset: u64, vlr: &[u8], point_count: u64, first: u64, end: u64, threads: usize, table_only: bool)
        -> Result<ScLazReader, String> {
    let vlr = LazVlr::from_buffer(vlr).map_err(|e| format!("LASzip VLR: {}", e))?;
    let point_size = vlr.items_size();
    let chunk_size = if vlr.uses_variable_size_chunks() { 0 } else { u64::from(vlr.chunk_size()) };
    let open_at_data = || -> Result<BufReader<Input>, String> { Ok(BufReader::with_capacity(1 << 16, file.at(data_offset))) };

    // The chunk table (at the end of the file) says how many points there are:
    // a truncated file or a wrong header count fails here, before any work.
    let table_offset = check_chunk_count(&file, data_offset, point_count, chunk_size)?;
    let table = match ChunkTable::read_from(open_at_data()?, &vlr) {
        Ok(table) => table,
        Err(e) => return Err(format!("cannot read the chunk table (truncated file?): {}", e)),
    };
    let mut table = table.as_ref().to_vec();
    let chunks = table.len() as u64;
    if chunk_size == 0 {
        let total = table.iter().try_fold(0u64, |t, e| t.checked_add(e.point_count));
        if total != Some(point_count) {
            return Err(format!("header declares {} points, the chunk table holds {}", point_count,
                               total.map_or("more than 2^64".to_string(), |t| t.to_string())));
        }
    } else if point_count > chunks * chunk_size || (chunks > 0 && point_count <= (chunks - 1) * chunk_size) {
        return Err(format!(
            "header declares {} points, the chunk table has {} chunks of {} points",
            point_count, chunks, chunk_size
        ));
    } else if let Some(last) = table.last_mut() {
        last.point_count = point_count - (chunks - 1) * chunk_size;  // the table gives every fixed chunk chunk_size
    }
    // Every chunk lies between the point data's start and the table, in
    // bytes its points could need: what a reader allocates is bounded by them.
    let mut starts = Vec::with_capacity(table.len());
    let (mut at_point, mut at_byte) = (0u64, data_offset + 8);  // past the chunk table's offset
    for (k, e) in table.iter().enumerate() {
        if e.byte_count > most_compressed(e.point_count.saturating_mul(point_size)) || e.byte_count > table_offset - at_byte {
            return Err(format!("chunk {} claims {} bytes for {} points at byte {}, the chunk table starting at byte {}", k,
                               e.byte_count, e.point_count, at_byte, table_offset));
        }
        starts.push((at_point, at_byte));
        at_point += e.point_count;
        at_byte += e.byte_count;
    }

    if table_only {
        return Ok(ScLazReader { decompressor: Decompressor::TableOnly, point_size, chunk_size, starts });
    }
    if first != 0 || end != point_count {
        return open_range(file, vlr, &table, &starts, first, end, point_size, chunk_size, threads);
    }

    // Chunks are the unit of parallel decoding: a file of one chunk (small
    // tiles, thousands per scan), or one whose chunks are too large to decode
    // whole, decodes on the caller's thread as a stream.
    let biggest = table.iter().map(|e| e.point_count).max().unwrap_or(0);
    if threads > 1 && chunks > 1 && point_count > 0 && biggest.saturating_mul(point_size) <= RANGE_CHUNK_BYTES {
        return open_range(file, vlr, &table, &starts, 0, point_count, point_size, chunk_size, threads);
    }
    let offsets: Vec<u64> = starts.iter().map(|s| s.1).collect();
    check_layer_sizes(&file, &vlr, &table, &offsets, 0)?;
    let d = LasZipDecompressor::new(open_at_data()?, vlr).map_err(|e| format!("{}", e))?;
    Ok(ScLazReader { decompressor: Decompressor::Sequential(d), point_size, chunk_size, starts })
}

// A reader of the points [first, end), both chunk starts (or `end` the point count).
#[allow(clippy::too_many_arguments)]
fn open_range(file: Input, vlr: LazVlr, table: &[ChunkTableEntry], starts: &[(u64, u64)], first: u64, end: u64, point_size: u64,
              chunk_size: u64, threads: usize) -> Result<ScLazReader, String> {
    let chunk_at = |point: u64| {
        if point == starts.last().map_or(0, |s| s.0) + table.last().map_or(0, |e| e.point_count) {
            Some(starts.len())  // the end of the file
        } else {
            starts.binary_search_by_key(&point, |s| s.0).ok()
        }
    };
    let (a, b) = match (chunk_at(first), chunk_at(end)) {
        (Some(a), Some(b)) if a < b => (a, b),
        _ => return Err(format!("points {}-{} are not a run of whole chunks", first, end.wrapping_sub(1))),
    };
    let chunks = table[a..b].to_vec();
    if let Some((k, e)) = chunks.iter().enumerate().find(|(_, e)| e.point_count.saturating_mul(point_size) > RANGE_CHUNK_BYTES) {
        return Err(format!("chunk {} claims {} points, over {} MiB decoded", a + k, e.point_count, RANGE_CHUNK_BYTES >> 20));
    }
    let offsets: Vec<u64> = starts[a..b].iter().map(|s| s.1).collect();
    check_layer_sizes(&file, &vlr, &chunks, &offsets, a)?;
    let range = ChunkRange { file, vlr, chunks, offsets, next: 0, rest: Vec::new(), taken: 0, failed: None, pool: shared_pool(threads)? };
    Ok(ScLazReader { decompressor: Decompressor::Range(range), point_size, chunk_size, starts: starts.to_vec() })
}

#[no_mangle]
pub extern "C" fn sc_laz_open(
    file_size: u64,
    read_at: Option<ScReadAt>,
    ctx: *mut c_void,
    data_offset: u64,
    vlr: *const u8,
    vlr_len: usize,
    point_count: u64,
    first: u64,
    end: u64,
    threads: c_int,
    table_only: c_int,
    err: *mut c_char,
    err_len: usize,
) -> *mut ScLazReader {
    let read_at = match read_at {
        Some(f) if !vlr.is_null() => f,
        _ => {
            write_err(err, err_len, "null argument");
            return std::ptr::null_mut();
        }
    };
    let file = Input { read_at, ctx, size: file_size, pos: 0 };
    // SAFETY: the caller passes vlr_len readable bytes.
    let vlr = unsafe { std::slice::from_raw_parts(vlr, vlr_len) };
    let threads = threads.max(1) as usize;
    match catch_unwind(AssertUnwindSafe(|| open(file, data_offset, vlr, point_count, first, end, threads, table_only != 0))) {
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
pub extern "C" fn sc_laz_chunk_count(reader: *const ScLazReader) -> u64 {
    // SAFETY: reader comes from sc_laz_open.
    unsafe { reader.as_ref() }.map_or(0, |r| r.starts.len() as u64)
}

#[no_mangle]
pub extern "C" fn sc_laz_chunk_start(reader: *const ScLazReader, chunk: u64, first_point: *mut u64, first_byte: *mut u64) -> c_int {
    // SAFETY: reader comes from sc_laz_open; the outputs are writable.
    match unsafe { reader.as_ref() }.and_then(|r| r.starts.get(chunk as usize)) {
        Some(&(point, byte)) if !first_point.is_null() && !first_byte.is_null() => {
            unsafe {
                *first_point = point;
                *first_byte = byte;
            }
            0
        }
        _ => -1,
    }
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
        Decompressor::Range(r) => r.read(out),
        Decompressor::TableOnly => Err("opened for its chunk table only".to_string()),
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
