// Publishing a finished folder (a tile set, an export) to an S3 prefix, so
// that the store, or a CDN in front of it, serves it as any static host does
// (docs/STORAGE.md). The objects are the folder's files, byte for byte, under
// the same names: `aws s3 sync` moves a set either way.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "status.h"
#include "tileset_format.h"

namespace surfcast {

struct PublishReport {
    uint64_t objects = 0, bytes = 0;
    uint64_t requests = 0;  // to the store, retries included
    uint64_t removed = 0;   // objects no kept version names (publishVersion)
    std::string warning;    // publishVersion: what went wrong after the switch (the version stands)
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

// One version of a set in a store, as an update or a compaction read it.
struct StoredVersion {
    std::string url;        // the set: s3://BUCKET/PREFIX/
    std::string etag;       // of its tileset.json
    int64_t modified = -1;  // its tileset.json's Last-Modified (seconds since 1970)
    TilesetInfo info;
};

// Copies the tileset.json of the set at s3://BUCKET/PREFIX, and its build
// record where it keeps one, into `folder` (which must exist): the metadata
// an update reads and rewrites locally (update.h, UpdateRequest::store).
Result<StoredVersion> mirrorSetMetadata(const std::string& url, const std::string& folder);

// Publishes the version an update or a compaction wrote into `folder` (its
// tileset.json, and the files it names that base's does not) as the set's
// next version, after `base` (docs/STORAGE.md, "Updates"):
//  1. the new files, with If-None-Match: * (one of an older, unnamed
//     version's that holds the same name is written again, so that its age
//     tells step 3 it is in use);
//  2. tileset.json with If-Match: base's ETag, so that of two updates of one
//     version exactly one wins; the other fails here, naming the set, which
//     stays as the winner wrote it;
//  3. the objects of the set (versionFileName) that neither version names
//     and that the store made before base's tileset.json go: earlier
//     versions', and those of updates that lost or failed. An object made
//     since may be an upload of an update of this very version, and stays;
//     each is asked again (HEAD) just before its DELETE, and an object of
//     step 1 that a racing step 3 deleted anyway is written once more
//     after the switch. (A DELETE landing between that HEAD and a racing
//     re-write is the window left.) A failure in step 3 is a warning: the
//     version stands.
// A failed publish deletes nothing (an update of the same bytes racing it
// may share its objects' names): step 3 of the next update removes them.
Result<PublishReport> publishVersion(const std::string& folder, const StoredVersion& base);

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
