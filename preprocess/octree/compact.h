// --compact: a set written anew without the blocks its updates replaced, its
// nodes' bytes (and so their ETags) as they were.
#pragma once

#include <cstdint>
#include <string>

#include "status.h"

namespace surfcast {

struct CompactReport {
    uint64_t blocksBytes = 0;  // the compacted set's
    uint64_t before = 0;       // its block files' bytes before
    bool already = false;      // a set in a store that was compact already: nothing written
    uint64_t requests = 0, removed = 0;  // to the store, and objects deleted there
};

// The set in folder `dir`, swapped whole for its compacted copy
// (tileset_writer.h): blocks.bin and hierarchy.bin again. The caller holds
// the set's lock (set_lock.h).
Result<CompactReport> compactFolder(const std::string& dir);

// The set at s3://BUCKET/PREFIX, compacted in a local folder (`staging`) and
// published as its next version (set_publisher.h, publishVersion): its
// blocks in one new file, blocks-XXXXXXXX.bin, beside a new hierarchy, as
// objects are never rewritten. A compaction that loses to an update fails,
// leaving the update's version; the previous version's objects stay for
// readers that opened it.
Result<CompactReport> compactStored(const std::string& url, const std::string& staging);

// surfcast-build --compact SET: a folder's set under its lock
// (compactFolder), or an s3:// set through a staging folder of its own
// (compactStored).
Result<CompactReport> compactSet(const std::string& set);

}  // namespace surfcast
