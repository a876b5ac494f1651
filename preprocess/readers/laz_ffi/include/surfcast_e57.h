/* C ABI of the E57 reader in the surfcast_laz Rust static library
 * (preprocess/readers/laz_ffi/src/e57_ffi.rs, the `e57` crate). Reads every
 * scan of a file in order, whose bytes the caller reads for it (ScReadAt, as
 * for LAZ). Errors come back as text in `err`, naming the scan. */
#ifndef SURFCAST_E57_H
#define SURFCAST_E57_H

#include <stddef.h>
#include <stdint.h>

#include "surfcast_laz.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct ScE57Reader ScE57Reader;

/* A scan (an E57 Data3D entry). */
typedef struct {
    uint64_t points;     /* records the file declares */
    double origin[3];    /* the pose's translation: where the scanner stood, in file coordinates */
    uint8_t has_pose;    /* 0: no pose element (origin is 0, 0, 0) */
    uint8_t spherical;   /* has spherical coordinates (range, azimuth, elevation) */
    uint8_t cartesian;   /* has cartesian coordinates */
    uint8_t color;
    uint8_t intensity;
    uint8_t row_column;  /* has row and column indices */
    uint8_t intensity_normalized;  /* its intensities come normalized by limits (else raw values) */
} ScE57Scan;

/* A point, with its scan's pose applied and spherical coordinates converted. */
typedef struct {
    double position[3];
    float intensity;     /* 0..1 by the scan's limits, raw where it has none (ScE57Scan); NaN: absent or invalid */
    float color[3];      /* 0..1 by the scan's limits; NaN: absent or invalid */
    int64_t row, column; /* -1 where the scan has none */
    uint32_t scan;       /* index of the scan the point belongs to */
    uint8_t valid;       /* 0: no return (invalid state, or a direction without range) */
    uint8_t pad[3];
} ScE57Point;

/* Opens a file of `file_size` bytes, read through `read_at(ctx, ...)` from the
 * thread that calls these functions. Checks the header, parses the XML and
 * every scan's prototype (cartesian or spherical coordinates, a unit pose
 * quaternion). Returns NULL on error. */
ScE57Reader* sc_e57_open(uint64_t file_size, ScReadAt read_at, void* ctx, char* err, size_t err_len);

uint64_t sc_e57_scan_count(const ScE57Reader* reader);
/* Images in the file (not read). */
uint64_t sc_e57_image_count(const ScE57Reader* reader);
/* Scan `scan`'s description, and its name as errors give it ("scan 2 ('Station 3')").
 * Returns 0, or -1 where there is no such scan. */
int sc_e57_scan(const ScE57Reader* reader, uint64_t scan, ScE57Scan* out, char* name, size_t name_len);

/* Reads the next points, scan after scan, into `out` (room for `max`):
 * returns how many (0: the end), or -1 with a message in `err`; a reader that
 * failed fails every later read. */
int64_t sc_e57_read(ScE57Reader* reader, ScE57Point* out, uint64_t max, char* err, size_t err_len);

void sc_e57_close(ScE57Reader* reader);

#ifdef __cplusplus
}
#endif

#endif
