// Follows a tile set as it changes (surfcast-build --add, --replace,
// --compact, or a rebuild): polls its tileset.json every interval, with
// If-None-Match on http(s) hosts (a 304 costs a few hundred bytes), and when
// it differs from the version shown, opens the new version as a
// StreamingSet in the background, ready for take(). A poll or an open that
// fails (a host gone, a torn answer, a version whose files a later update
// already deleted) is a transient fault: tried again at the next poll.
// Destroying the watcher cancels the requests in flight: it never waits for
// a stalled host.
#pragma once

#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "streamer.h"

namespace surfcast {

class VersionWatcher {
public:
    // Watches `location`, shown now as `shown` (its tileset.json's bytes);
    // new versions open with `options`.
    VersionWatcher(std::string location, StreamOptions options, std::vector<uint8_t> shown, double intervalSeconds);
    ~VersionWatcher();
    VersionWatcher(const VersionWatcher&) = delete;
    VersionWatcher& operator=(const VersionWatcher&) = delete;

    // The newest version opened and not yet taken, if any (an older one not
    // taken in time is dropped).
    std::unique_ptr<StreamingSet> take();
    // The version taken could not be shown after all (its stream gave up):
    // the watcher takes `shown` as the version shown again, and opens the
    // newest version anew at its next poll (unless a newer one is ready).
    void showing(std::vector<uint8_t> shown);
    // Polls so far, and the last poll's or open's error ("" after a success).
    size_t polls() const;
    std::string lastError() const;

private:
    void loop();

    const std::string location_;
    StreamOptions options_;
    const double interval_;
    mutable std::mutex mutex_;
    std::condition_variable wake_;
    std::vector<uint8_t> shown_;  // the newest version opened (or shown)
    std::unique_ptr<StreamingSet> ready_;
    bool reread_ = false;  // showing(): read tileset.json whole at the next poll
    size_t polls_ = 0;
    std::string lastError_;
    bool stopping_ = false;
    // The sources the poll and the opening of a new version read through,
    // for the destructor to cancel.
    std::shared_ptr<TileSource> polling_, opening_;
    std::thread thread_;  // last: starts once the rest is ready
};

}  // namespace surfcast
