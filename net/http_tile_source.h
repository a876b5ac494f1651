// The project's only HTTP client code: a tile set read from an http(s) folder
// URL (the project's server at http://HOST:PORT/sets/NAME, or any static host,
// object store or CDN that honours Range), for the viewer's streamer, the
// readers of surfcast-build --info and surfcast-view without --lod. libcurl:
// TLS verified against the system store, HTTP/2 where the host offers it,
// proxies from the environment, redirects followed to http(s) only, never from
// https to http, and the user's headers sent to the set's own origin only.
#pragma once

#include <functional>
#include <memory>
#include <string>

#include "status.h"
#include "tile_source.h"
#include "tileset_reader.h"

namespace surfcast {

// An http(s) URL opens an HTTP source (all requests run on one libcurl multi
// handle driven by one I/O thread: one multiplexed connection over HTTP/2, up
// to 6 keep-alive connections over HTTP/1.1; a query string, such as a shared
// access signature, is kept on every request and left out of messages); an
// s3://BUCKET/PREFIX URL the same source on the store's endpoint, its file
// names object keys, every request signed with SigV4 where the AWS chain
// gives credentials (object_store.h); anything else is a local folder
// (openFolderSource).
Result<std::unique_ptr<TileSource>> openTileSource(const std::string& location, const HttpOptions& http = {});

// A reader of the set at a folder, an http(s) URL or an s3:// URL; a
// transient fault of a request is asked again (HttpOptions::retries, at least 3).
Result<TilesetReader> openTileset(const std::string& location, const HttpOptions& http = {});

}  // namespace surfcast
