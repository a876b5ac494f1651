//! LAZ compression through the `laz` crate, exposed to C++ (see
//! include/surfcast_laz.h, "Writing"). The output is a stream that never
//! seeks back: the chunk table's offset at the start of the point data stays
//! -1, and either the offset follows the chunk table as the file's last 8
//! bytes, which LASzip readers look for there (so that a server can send the
//! file as it is compressed), or the caller writes it over the -1 itself (a
//! file with EVLRs after the table: COPC). Panics never cross the boundary.

use std::io::{Seek, SeekFrom, Write};
use std::os::raw::{c_char, c_int, c_void};
use std::panic::{catch_unwind, AssertUnwindSafe};

use laz::{LasZipCompressor, LazVlr, LazVlrBuilder};

use crate::{panic_message, write_err};

/// Appends `len` bytes to the output: 0, or -1 on an error.
pub type ScWrite = extern "C" fn(ctx: *mut c_void, data: *const u8, len: u64) -> c_int;

// Bytes gathered before a call to the caller's function.
const FLUSH_BYTES: usize = 1 << 20;

// The output as the compressor sees it: positions are the file's, from the
// point data's start on; the only write behind the end is the chunk table's
// offset over its reserved -1, which is kept for the file's end instead.
struct Stream {
    write: ScWrite,
    ctx: *mut c_void,
    buffer: Vec<u8>,
    flushed: u64, // file position of buffer[0]
    pos: u64,
    start: u64,   // the point data's first byte: where the chunk table's offset goes
    offset: Option<[u8; 8]>,
}

// SAFETY: used on the thread that calls the sc_laz_writer functions only
// (the `laz` crate asks for Sync of what it writes to, and shares it with no thread).
unsafe impl Send for Stream {}
unsafe impl Sync for Stream {}

impl Stream {
    fn end(&self) -> u64 {
        self.flushed + self.buffer.len() as u64
    }
    fn flush_buffer(&mut self) -> std::io::Result<()> {
        if !self.buffer.is_empty() {
            if (self.write)(self.ctx, self.buffer.as_ptr(), self.buffer.len() as u64) != 0 {
                return Err(std::io::Error::new(std::io::ErrorKind::Other, "the output refused the bytes"));
            }
            self.flushed += self.buffer.len() as u64;
            self.buffer.clear();
        }
        Ok(())
    }
}

impl Write for Stream {
    fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
        if self.pos < self.end() {
            if data.len() == 8 && self.pos == self.start && self.offset.is_none() {
                self.offset = Some(data.try_into().unwrap());
                self.pos += 8;
                return Ok(8);
            }
            return Err(std::io::Error::new(std::io::ErrorKind::Other, "a write behind the stream's end"));
        }
        self.buffer.extend_from_slice(data);
        self.pos += data.len() as u64;
        if self.buffer.len() >= FLUSH_BYTES {
            self.flush_buffer()?;
        }
        Ok(data.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Seek for Stream {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        self.pos = match to {
            SeekFrom::Start(n) if n <= self.end() => n,
            SeekFrom::Current(0) => self.pos,
            SeekFrom::End(0) => self.end(),
            _ => return Err(std::io::Error::new(std::io::ErrorKind::Other, "an unsupported seek on a stream")),
        };
        Ok(self.pos)
    }
}

pub struct ScLazWriter {
    compressor: LasZipCompressor<'static, Stream>,
    point_size: usize,
    chunk_start: u64, // the open chunk's first byte
}

fn vlr_for(point_format: u8, extra_bytes: u16, variable_chunks: bool) -> Result<LazVlr, String> {
    let builder = LazVlrBuilder::default()
        .with_point_format(point_format, extra_bytes)
        .map_err(|e| format!("point format {}: {}", point_format, e))?;
    Ok(if variable_chunks { builder.with_variable_chunk_size() } else { builder }.build())
}

/// The LASzip VLR's payload for `point_format` (0-10) with `extra_bytes`
/// bytes per record beyond the format's, chunks of 50,000 points or of
/// variable size: written into `out` (room for `cap`), its length in `len`.
/// Returns 0, or -1 (too small, or no such format).
#[no_mangle]
pub extern "C" fn sc_laz_vlr(point_format: u8, extra_bytes: u16, variable_chunks: c_int, out: *mut u8, cap: usize,
                             len: *mut usize) -> c_int {
    let result = catch_unwind(|| -> Result<Vec<u8>, String> {
        let mut bytes = Vec::new();
        vlr_for(point_format, extra_bytes, variable_chunks != 0)?.write_to(&mut bytes).map_err(|e| e.to_string())?;
        Ok(bytes)
    });
    match result {
        Ok(Ok(bytes)) if bytes.len() <= cap && !out.is_null() && !len.is_null() => {
            // SAFETY: the caller gives `cap` writable bytes at out.
            unsafe {
                std::ptr::copy_nonoverlapping(bytes.as_ptr(), out, bytes.len());
                *len = bytes.len();
            }
            0
        }
        _ => -1,
    }
}

/// A compressor of `point_format` records whose point data starts at byte
/// `data_offset` of the file, its bytes handed to `write(ctx, ...)` in order.
#[no_mangle]
pub extern "C" fn sc_laz_writer_open(write: Option<ScWrite>, ctx: *mut c_void, data_offset: u64, point_format: u8,
                                     extra_bytes: u16, variable_chunks: c_int, err: *mut c_char, err_len: usize)
                                     -> *mut ScLazWriter {
    let Some(write) = write else {
        write_err(err, err_len, "null argument");
        return std::ptr::null_mut();
    };
    let result = catch_unwind(AssertUnwindSafe(|| -> Result<ScLazWriter, String> {
        let vlr = vlr_for(point_format, extra_bytes, variable_chunks != 0)?;
        let point_size = vlr.items_size() as usize;
        let stream = Stream { write, ctx, buffer: Vec::new(), flushed: data_offset, pos: data_offset, start: data_offset, offset: None };
        let mut compressor = LasZipCompressor::new(stream, vlr).map_err(|e| e.to_string())?;
        compressor.reserve_offset_to_chunk_table().map_err(|e| e.to_string())?;
        Ok(ScLazWriter { compressor, point_size, chunk_start: data_offset + 8 })
    }));
    match result {
        Ok(Ok(w)) => Box::into_raw(Box::new(w)),
        Ok(Err(message)) => {
            write_err(err, err_len, &message);
            std::ptr::null_mut()
        }
        Err(p) => {
            write_err(err, err_len, &format!("LAZ compressor panicked: {}", panic_message(p)));
            std::ptr::null_mut()
        }
    }
}

fn run(writer: *mut ScLazWriter, err: *mut c_char, err_len: usize,
       f: impl FnOnce(&mut ScLazWriter) -> std::io::Result<()>) -> c_int {
    // SAFETY: writer comes from sc_laz_writer_open.
    let Some(w) = (unsafe { writer.as_mut() }) else {
        write_err(err, err_len, "null writer");
        return -1;
    };
    match catch_unwind(AssertUnwindSafe(|| f(w))) {
        Ok(Ok(())) => 0,
        Ok(Err(e)) => {
            write_err(err, err_len, &e.to_string());
            -1
        }
        Err(p) => {
            write_err(err, err_len, &format!("LAZ compressor panicked: {}", panic_message(p)));
            -1
        }
    }
}

/// Compresses `count` records of the format's size from `records`. Returns 0, or -1.
#[no_mangle]
pub extern "C" fn sc_laz_writer_write(writer: *mut ScLazWriter, records: *const u8, count: u64, err: *mut c_char,
                                      err_len: usize) -> c_int {
    run(writer, err, err_len, |w| {
        let len = usize::try_from(count).ok().and_then(|c| c.checked_mul(w.point_size))
            .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "too many records"))?;
        // SAFETY: the caller gives count records at `records`.
        let bytes = unsafe { std::slice::from_raw_parts(records, len) };
        w.compressor.compress_many(bytes)
    })
}

/// Ends the chunk open (variable-size chunks only; the caller ends none
/// without points) and gives its first byte and its size in the file.
/// Returns 0, or -1.
#[no_mangle]
pub extern "C" fn sc_laz_writer_end_chunk(writer: *mut ScLazWriter, first_byte: *mut u64, bytes: *mut u64, err: *mut c_char,
                                          err_len: usize) -> c_int {
    run(writer, err, err_len, |w| {
        if first_byte.is_null() || bytes.is_null() {
            return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "null argument"));
        }
        if !w.compressor.vlr().uses_variable_size_chunks() {
            return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "fixed-size chunks end by themselves"));
        }
        w.compressor.finish_current_chunk()?;
        let end = w.compressor.get_mut().end();
        // SAFETY: checked non-null above; the caller gives writable u64s.
        unsafe {
            *first_byte = w.chunk_start;
            *bytes = end - w.chunk_start;
        }
        w.chunk_start = end;
        Ok(())
    })
}

/// Ends the last chunk (its first byte and size in `last_first`, `last_bytes`
/// where not null) and writes the chunk table; `table` (where not null)
/// gets the table's offset. With `append_offset` the offset follows as the
/// file's last 8 bytes (a stream); else the caller writes it over the
/// point data's first 8 bytes itself (a file it can seek in). 0, or -1.
#[no_mangle]
pub extern "C" fn sc_laz_writer_finish(writer: *mut ScLazWriter, append_offset: c_int, last_first: *mut u64,
                                       last_bytes: *mut u64, table: *mut u64, err: *mut c_char, err_len: usize) -> c_int {
    run(writer, err, err_len, |w| {
        w.compressor.done()?;
        let chunk_start = w.chunk_start;
        let stream = w.compressor.get_mut();
        let offset = stream.offset.take().ok_or_else(|| std::io::Error::new(std::io::ErrorKind::Other, "no chunk table offset"))?;
        let table_at = u64::from_le_bytes(offset);
        // SAFETY: the caller gives writable u64s where not null.
        unsafe {
            if !last_first.is_null() {
                *last_first = chunk_start;
            }
            if !last_bytes.is_null() {
                *last_bytes = table_at - chunk_start;
            }
            if !table.is_null() {
                *table = table_at;
            }
        }
        stream.pos = stream.end();
        if append_offset != 0 {
            stream.write_all(&offset)?;
        }
        stream.flush_buffer()
    })
}

#[no_mangle]
pub extern "C" fn sc_laz_writer_close(writer: *mut ScLazWriter) {
    if !writer.is_null() {
        // SAFETY: writer comes from sc_laz_writer_open and is closed once.
        drop(unsafe { Box::from_raw(writer) });
    }
}
