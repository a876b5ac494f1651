// A staged build's work folder in an object store (--work s3://BUCKET/PREFIX):
// each stage's process copies the work files it reads into a folder of its
// own, runs on that folder as on a shared one, and uploads what it wrote
// (the shuffle's pieces as LZ4 frames, NAME.lz4), so that the machines of a
// cluster share nothing but the store
// (docs/STORAGE.md, "Builds across machines"). The work files are
// deterministic: a task run again writes the same bytes, and a PUT replaces
// an object whole, so a worker killed during its upload leaves either
// nothing or the same bytes.
#pragma once

#include <cstddef>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "status.h"

namespace surfcast {

class StoreWork {
public:
    // Copies into `local` (a new folder) the work files `stage` reads:
    //   count            scan/
    //   plan             scan/, count/
    //   distribute       plan.bin
    //   chunk I...       plan.bin, each part's distribution.bin and its pieces of chunks I...
    //   merge            plan.bin, nodes/
    static Result<std::unique_ptr<StoreWork>> open(const std::string& url, const std::string& stage, const std::vector<size_t>& chunks,
                                                   const std::string& local);
    const std::string& dir() const { return local_; }
    // Uploads the files under dir() the stage wrote, each output's files
    // before the one that marks it whole (a part's distribution.bin, a
    // chunk's .nodes, plan.json after plan.bin), which a driver resuming
    // from the store checks.
    Status upload() const;
    // Deletes the work's objects under these prefixes of it ("chunks/").
    Status remove(const std::vector<std::string>& prefixes) const;

private:
    std::string bucket_, prefix_, local_;
    std::set<std::string> copied_;  // relative paths copied in
};

}  // namespace surfcast
