// A folder written whole beside its final place and swapped in, so that a
// reader of the output finds the old folder or the new one, never a mix.
// The writer puts everything into a hidden folder beside the output
// (".NAME.partial-PID", path()), its marker file (tileset.json) last, and
// publish() exchanges it with the output in one step (renameat2
// RENAME_EXCHANGE); where the file system cannot exchange, the old folder is
// moved aside (".NAME.old-PID") and the new one moved in. A writer killed at
// any moment leaves the output holding the old folder or the new one, whole,
// or (in the fallback's one gap, or a first write) nothing; and hidden
// folders beside it, which the next writer into the same output removes (an
// old folder moved aside goes back if the output is empty). Used by the tile
// set writer (bad_input_test's kill-anywhere test checks it at 20 random
// moments) and by surfcast-export's 3D Tiles.
#pragma once

#include <functional>
#include <memory>
#include <string>

#include "status.h"

namespace surfcast {

class PublishedFolder {
public:
    // `replaceable` says whether an existing, non-empty output is one this
    // writer may replace (else: an error, never clobbering other data);
    // `what` names that kind of folder in the error. `marker` is the file
    // whose presence makes a folder whole: the old folder loses it first.
    // `tag`: where one process writes the output twice at once (a build and
    // its refinements: refine.h), each writer's own, named in the partial
    // folder (".NAME.partial-PID-TAG").
    static Result<std::unique_ptr<PublishedFolder>> create(const std::string& output, const std::string& marker,
                                                           const std::function<bool(const std::string&)>& replaceable,
                                                           const std::string& what, const std::string& tag = "");
    ~PublishedFolder();  // removes the partial folder unless publish() succeeded

    const std::string& path() const { return partial_; }  // where to write
    const std::string& output() const { return output_; }
    Status publish();

private:
    PublishedFolder() = default;
    std::string output_, partial_, marker_;
    bool published_ = false;
};

// Writes a file and flushes it to disk before returning.
Status writeFileSynced(const std::string& path, const void* data, size_t size);

}  // namespace surfcast
