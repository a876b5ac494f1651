#include "s3_xml.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <ctime>
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

std::optional<int64_t> parseIsoTime(const std::string& text) {
    // YYYY-MM-DDTHH:MM:SS, then an optional .fraction, then Z.
    static const char kShape[] = "dddd-dd-ddTdd:dd:dd";
    if (text.size() < 20) return std::nullopt;
    for (size_t i = 0; i + 1 < sizeof kShape; ++i)
        if (kShape[i] == 'd' ? !std::isdigit(static_cast<unsigned char>(text[i])) : text[i] != kShape[i]) return std::nullopt;
    size_t end = 19;
    if (text[end] == '.')
        for (++end; end < text.size() && std::isdigit(static_cast<unsigned char>(text[end]));) ++end;
    if (end + 1 != text.size() || text[end] != 'Z') return std::nullopt;
    auto number = [&](size_t at, size_t digits) { return std::stoi(text.substr(at, digits)); };
    std::tm t{};
    t.tm_year = number(0, 4) - 1900;
    t.tm_mon = number(5, 2) - 1;
    t.tm_mday = number(8, 2);
    t.tm_hour = number(11, 2);
    t.tm_min = number(14, 2);
    t.tm_sec = number(17, 2);
    if (t.tm_mon > 11 || t.tm_mday < 1 || t.tm_mday > 31 || t.tm_hour > 23 || t.tm_min > 59 || t.tm_sec > 60) return std::nullopt;
    return int64_t(timegm(&t));
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
        const auto modified = xmlElement(*contents, "LastModified");
        page.objects.push_back({*key, n, etag.value_or(""), modified ? parseIsoTime(*modified).value_or(-1) : -1});
    }
    page.truncated = xmlElement(xml, "IsTruncated").value_or("") == "true";
    if (page.truncated) page.next = xmlElement(xml, "NextContinuationToken").value_or("");
    return page;
}

}  // namespace surfcast
