// Publishing a finished folder (a tile set, an export) to an S3 prefix, so
// that the store, or a CDN in front of it, serves it as any static host does
// (docs/STORAGE.md). The objects are the folder's files, byte for byte, under
// the same names: `aws s3 sync` moves a set either way.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "status.h"

namespace surfcast {

struct PublishReport {
    uint64_t objects = 0, bytes = 0;
    uint64_t requests = 0;  // to the store, retries included
};

// Uploads every file under `folder` to s3://BUCKET/PREFIX/ (its path below
// the folder as the key's rest), `last` (a top-level file: tileset.json)
// after all the others, so that a reader that finds it finds the rest. A
// prefix that holds objects already is refused: a set's objects are never
// rewritten in place (a reader may be streaming them). Every object is
// written with If-None-Match: *, so of two publishers racing for one prefix
// at most one wins. A publish that fails names the object and the store's
// answer, and deletes what it wrote, unless a tileset.json stands at the
// prefix by then (its own, whose answer was lost, or a racing publisher's,
// whose set bears the same names), the store cannot say whether one does, or
// its own tileset.json's upload failed in a way the store may yet take it.
Result<PublishReport> publishFolder(const std::string& folder, const std::string& url, const std::string& last = "tileset.json");

// The local folder a set or an export is written in before its upload: a
// new $TMPDIR/surfcast-publish-XXXXXX, locked (flock) while this object
// lives and removed with it. Those of killed processes, whose lock nobody
// holds, are removed first.
class PublishStaging {
public:
    static Result<std::unique_ptr<PublishStaging>> create();
    ~PublishStaging();
    const std::string& dir() const { return dir_; }

private:
    std::string dir_;
    int lock_ = -1;
};

}  // namespace surfcast
