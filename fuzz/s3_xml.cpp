// libFuzzer target: an S3 store's XML answers (net/s3_xml.h), a ListObjectsV2
// page and the elements of an error, as object_store.cpp reads them.
#include <cstdint>
#include <string>

#include "s3_xml.h"

using namespace surfcast;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    const std::string xml(reinterpret_cast<const char*>(data), size);
    auto page = parseListPage(xml);
    if (page) {
        for (const ListedObject& o : page->objects)
            if (o.key.empty()) __builtin_trap();  // parseListPage promises a key
        if (!page->truncated && !page->next.empty()) __builtin_trap();
    }
    for (const char* tag : {"Code", "Message", "UploadId", "ETag"}) {
        auto text = xmlElement(xml, tag);
        if (text && text->size() > xml.size()) __builtin_trap();  // decoding never grows the text
    }
    return 0;
}
