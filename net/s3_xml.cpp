#include "s3_xml.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <map>

namespace surfcast {

std::optional<std::string> xmlElement(const std::string& xml, const std::string& tag, size_t* from, bool raw) {
    const std::string open = "<" + tag + ">", close = "</" + tag + ">";
    const size_t start = xml.find(open, from ? *from : 0);
    if (start == std::string::npos) return std::nullopt;
    const size_t end = xml.find(close, start + open.size());
    if (end == std::string::npos) return std::nullopt;
    if (from) *from = end + close.size();
    const std::string text = xml.substr(start + open.size(), end - start - open.size());
    if (raw) return text;
    std::string out;
    for (size_t i = 0; i < text.size(); ++i) {
        if (text[i] != '&') {
            out += text[i];
            continue;
        }
        const size_t semi = text.find(';', i);
        if (semi == std::string::npos) return std::nullopt;
        const std::string entity = text.substr(i + 1, semi - i - 1);
        static const std::map<std::string, char> named = {{"amp", '&'}, {"lt", '<'}, {"gt", '>'}, {"quot", '"'}, {"apos", '\''}};
        if (auto it = named.find(entity); it != named.end()) {
            out += it->second;
        } else if (entity.size() > 1 && entity[0] == '#') {
            const bool isHex = entity[1] == 'x';
            const std::string digits = entity.substr(isHex ? 2 : 1);
            // S3 escapes control characters only: one to three digits.
            if (digits.empty() || digits.size() > 3 ||
                !std::all_of(digits.begin(), digits.end(), [&](char c) { return isHex ? std::isxdigit(static_cast<unsigned char>(c)) : std::isdigit(static_cast<unsigned char>(c)); }))
                return std::nullopt;
            const unsigned long code = std::strtoul(digits.c_str(), nullptr, isHex ? 16 : 10);
            if (code == 0 || code > 0x7f) return std::nullopt;
            out += char(code);
        } else {
            return std::nullopt;
        }
        i = semi;
    }
    return out;
}

Result<ListPage> parseListPage(const std::string& xml) {
    ListPage page;
    size_t at = 0;
    while (auto contents = xmlElement(xml, "Contents", &at, true)) {
        const auto key = xmlElement(*contents, "Key"), size = xmlElement(*contents, "Size"), etag = xmlElement(*contents, "ETag");
        if (!key || key->empty() || !size) return Status::error("an entry without a Key or Size");
        // At most 20 digits: a uint64_t.
        if (size->empty() || size->size() > 20 || !std::all_of(size->begin(), size->end(), [](char c) { return c >= '0' && c <= '9'; }))
            return Status::error("the entry " + *key + " has a Size that is not a number");
        errno = 0;
        const unsigned long long n = std::strtoull(size->c_str(), nullptr, 10);
        if (errno != 0) return Status::error("the entry " + *key + " has a Size past 2^64");
        page.objects.push_back({*key, n, etag.value_or("")});
    }
    page.truncated = xmlElement(xml, "IsTruncated").value_or("") == "true";
    if (page.truncated) page.next = xmlElement(xml, "NextContinuationToken").value_or("");
    return page;
}

}  // namespace surfcast
