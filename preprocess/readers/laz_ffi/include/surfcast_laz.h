/* C ABI of the surfcast_laz Rust static library (preprocess/readers/laz_ffi).
 * Decompresses the point records of a LAZ file, whose bytes the caller reads
 * for it (a local file or a URL); the LAS header and VLRs are parsed by the
 * caller (las_reader.cpp). Compresses records into a LAZ stream whose header
 * the caller writes (export/laz_export.cpp). Errors come back as text in `err`. */
#ifndef SURFCAST_LAZ_H
#define SURFCAST_LAZ_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct ScLazReader ScLazReader;

/* Reads up to `len` bytes at `offset` of the file into `out`: returns the
 * bytes read (fewer only where the file ends), or -1 on an error. */
typedef int64_t (*ScReadAt)(void* ctx, uint64_t offset, uint8_t* out, uint64_t len);

/* Opens a file of `file_size` bytes, read through `read_at(ctx, ...)` from
 * the thread that calls sc_laz_open and sc_laz_read (one at a time), for
 * decompression of its points [first, end). `data_offset`: byte offset of the
 * point data (header field "offset to point data"); `vlr`: the payload of the
 * LASzip VLR (user "laszip encoded", record 22204); `point_count`: points the
 * header declares, checked against the chunk table. [0, point_count) reads
 * the whole file; any other range must start and end at chunk starts
 * (sc_laz_chunk_start) or the file's end. `threads` > 1 decompresses chunks
 * in parallel (rayon). `table_only`: read the chunk table only, for
 * sc_laz_chunk_*, and no points. Returns NULL on error. */
ScLazReader* sc_laz_open(uint64_t file_size, ScReadAt read_at, void* ctx, uint64_t data_offset, const uint8_t* vlr,
                         size_t vlr_len, uint64_t point_count, uint64_t first, uint64_t end, int threads, int table_only,
                         char* err, size_t err_len);

/* Bytes per decompressed point record, and points per chunk (0: variable). */
uint64_t sc_laz_point_size(const ScLazReader* reader);
uint64_t sc_laz_chunk_size(const ScLazReader* reader);

/* The file's chunks, and where chunk `chunk` starts: its first point and its
 * first byte in the file. Returns 0, or -1 where there is no such chunk. */
uint64_t sc_laz_chunk_count(const ScLazReader* reader);
int sc_laz_chunk_start(const ScLazReader* reader, uint64_t chunk, uint64_t* first_point, uint64_t* first_byte);

/* Decompresses the next `points` records into `out` (points * point_size
 * bytes). Returns 0, or -1 with a message in `err`. */
int sc_laz_read(ScLazReader* reader, uint8_t* out, uint64_t points, char* err, size_t err_len);

void sc_laz_close(ScLazReader* reader);

/* Writing (src/laz_writer.rs). The output is a stream that never seeks back:
 * the chunk table's offset at the start of the point data stays -1, and the
 * offset itself is the file's last 8 bytes, where LASzip readers look for it,
 * or the caller writes it over the -1 (sc_laz_writer_finish). */
typedef struct ScLazWriter ScLazWriter;

/* Appends `len` bytes to the output: returns 0, or -1 on an error. */
typedef int (*ScWrite)(void* ctx, const uint8_t* data, uint64_t len);

/* The LASzip VLR's payload (user "laszip encoded", record 22204) for point
 * format `point_format` with `extra_bytes` bytes per record beyond it, in
 * chunks of 50,000 points or, with `variable_chunks`, of the caller's choosing
 * (COPC), into `out` (room for `cap`), its length in `len`. 0, or -1. */
int sc_laz_vlr(uint8_t point_format, uint16_t extra_bytes, int variable_chunks, uint8_t* out, size_t cap, size_t* len);

/* A compressor of such records whose point data starts at byte `data_offset`
 * of the file (the caller writes the header and VLRs before it); its bytes go
 * to `write(ctx, ...)` in order, from the calling thread, starting with the
 * chunk table's offset as -1. NULL on error. */
ScLazWriter* sc_laz_writer_open(ScWrite write, void* ctx, uint64_t data_offset, uint8_t point_format, uint16_t extra_bytes,
                                int variable_chunks, char* err, size_t err_len);
/* Compresses `count` records (count * the format's size bytes). 0, or -1. */
int sc_laz_writer_write(ScLazWriter* writer, const uint8_t* records, uint64_t count, char* err, size_t err_len);
/* Variable-size chunks: ends the chunk open, giving its first byte and size. 0, or -1. */
int sc_laz_writer_end_chunk(ScLazWriter* writer, uint64_t* first_byte, uint64_t* bytes, char* err, size_t err_len);
/* Ends the last chunk (its range in last_first and last_bytes) and writes the
 * chunk table (its offset in `table`); outputs may be NULL. With
 * `append_offset` the table's offset follows as the file's last 8 bytes (a
 * stream); else the caller writes it over the point data's first 8 bytes (a
 * file it can seek in, with EVLRs after the table: COPC). 0, or -1. */
int sc_laz_writer_finish(ScLazWriter* writer, int append_offset, uint64_t* last_first, uint64_t* last_bytes, uint64_t* table,
                         char* err, size_t err_len);
void sc_laz_writer_close(ScLazWriter* writer);

#ifdef __cplusplus
}
#endif

#endif
