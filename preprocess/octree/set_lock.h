// One writer of a set at a time (a build or --merge over it, an update, a
// compaction, a weight capture): an exclusive lock on its folder, held from
// before the writer reads the set until the lock is destroyed (the process
// ends); another writer fails at once.
#pragma once

#include <string>

#include "status.h"

namespace surfcast {

struct SetLock {
    int fd = -1;
    SetLock() = default;
    SetLock(const SetLock&) = delete;
    SetLock& operator=(const SetLock&) = delete;
    ~SetLock();
};

// Locks the set in folder `set`; an error names it where another writer holds it.
Status lockSet(const std::string& set, SetLock* lock);

// The set `output` names, locked where it exists already (a new one has no
// other writer to wait for; a path that is no folder, TilesetWriter refuses).
Status lockOutput(const std::string& output, SetLock* lock);

}  // namespace surfcast
