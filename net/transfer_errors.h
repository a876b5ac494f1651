// Which failures of a request asking again may clear, for both of net/'s
// libcurl users (the HTTP tile source and the object store), so the two
// retry the same faults.
#pragma once

#include <curl/curl.h>

namespace surfcast {

// HTTP 408, 429 and 5xx but 501 (Not Implemented) and 505 (Version Not
// Supported), which answer the same again.
inline bool transientHttpStatus(long status) { return status == 408 || status == 429 || (status >= 500 && status != 501 && status != 505); }

// Transfer errors that asking again cannot clear: the URL, the protocol,
// the host's certificate. Everything else (refused or reset connections,
// timeouts, name lookups) may pass, as when a server restarts.
inline bool permanentTransferError(CURLcode code) {
    switch (code) {
    case CURLE_UNSUPPORTED_PROTOCOL:
    case CURLE_URL_MALFORMAT:
    case CURLE_PEER_FAILED_VERIFICATION:
    case CURLE_SSL_CACERT_BADFILE:
    case CURLE_SSL_CERTPROBLEM: return true;
    default: return false;
    }
}

}  // namespace surfcast
