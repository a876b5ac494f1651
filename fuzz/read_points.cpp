// libFuzzer target: one input file of a point format, read whole through the
// build's own input path (forEachInput: the reader chosen by extension and
// magic bytes, every scalar field asked for). Built once per format with
// FUZZ_EXTENSION (".ply", ".las", ".laz", ".pcd", ".xyz", ".obj"): the bytes go
// to a file of that name, since the readers take paths.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <string>

#include "fuzz_support.h"
#include "inputs.h"

using namespace surfcast;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    static const fuzz::ScratchFile scratch(FUZZ_EXTENSION);
    const std::string& path = scratch.path;
    if (!fuzz::writeScratch(path, data, size)) return 0;
    fuzz::readWhole(path);
    return 0;
}
