#include "text_reader.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <sstream>

#include "byte_stream.h"

namespace surfcast {

namespace {

enum XyzColumn { X, Y, Z, R, G, B, NX, NY, NZ, I, Ignore };

bool parseLayout(const std::string& layout, std::vector<XyzColumn>* fields) {
    static const std::pair<const char*, XyzColumn> kNames[] = {{"x", X},   {"y", Y},   {"z", Z},   {"r", R},
                                                           {"g", G},   {"b", B},   {"nx", NX}, {"ny", NY},
                                                           {"nz", NZ}, {"i", I},   {"_", Ignore}};
    fields->clear();
    std::stringstream ss(layout);
    std::string name;
    while (std::getline(ss, name, ',')) {
        bool found = false;
        for (auto [n, f] : kNames)
            if (name == n) { fields->push_back(f); found = true; }
        if (!found) return false;
    }
    auto has = [&](XyzColumn f) { return std::find(fields->begin(), fields->end(), f) != fields->end(); };
    return has(X) && has(Y) && has(Z);
}

// Splits a line into numbers; false when a token is not a number.
bool splitNumbers(const std::string& line, std::vector<double>* out) {
    out->clear();
    const char* p = line.data();
    const char* end = p + line.size();
    while (p < end) {
        while (p < end && (*p == ' ' || *p == '\t' || *p == ',' || *p == ';')) ++p;
        if (p == end) break;
        double v = 0;
        auto [next, ec] = std::from_chars(p, end, v);
        if (ec != std::errc()) {
            // nan/inf spellings: accept them so the point is counted as skipped.
            const char* q = p;
            while (q < end && *q != ' ' && *q != '\t' && *q != ',' && *q != ';') ++q;
            std::string tok(p, q);
            char* stop = nullptr;
            v = std::strtod(tok.c_str(), &stop);
            if (stop != tok.c_str() + tok.size()) return false;
            next = q;
        }
        out->push_back(v);
        p = next;
    }
    return true;
}

class TextReader final : public PointReader {
public:
    TextReader(ByteStream in, InputDescription desc, std::vector<XyzColumn> fields)
        : in_(std::move(in)), desc_(std::move(desc)), fields_(std::move(fields)) {}

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        size_t n = 0;
        while (n < max && in_.readLine(&line_)) {
            if (line_.empty() || line_[0] == '#' || line_.find_first_not_of(" \t\r,") == std::string::npos) continue;
            uint64_t lineNo = in_.line() - 1;
            if (!splitNumbers(line_, &values_))
                return Status::error(desc_.path + ": line " + std::to_string(lineNo) + ": not a row of numbers");
            if (values_.size() == 1 && !sawData_) continue;  // PTS point count
            if (values_.size() < fields_.size())
                return Status::error(desc_.path + ": line " + std::to_string(lineNo) + ": " + std::to_string(values_.size()) +
                                     " columns, the layout needs " + std::to_string(fields_.size()));
            sawData_ = true;
            InputPoint& p = out[n];
            p = InputPoint{};
            Vec3f normal;
            for (size_t c = 0; c < fields_.size(); ++c) {
                double v = values_[c];
                switch (fields_[c]) {
                    case X: p.position.x = v; break;
                    case Y: p.position.y = v; break;
                    case Z: p.position.z = v; break;
                    case R: case G: case B:
                        p.color[fields_[c] - R] = uint16_t(saturate16(std::min(v, 255.0)) * 257);
                        break;
                    case NX: case NY: case NZ: normal[fields_[c] - NX] = float(v); break;
                    case I: p.intensity = saturate16(v); break;
                    case Ignore: break;
                }
            }
            p.normal = normalizeOrZero(normal);
            if (finite(p.position)) ++n; else ++skipped_;
        }
        if (in_.failed()) return Status::error(in_.atLine());  // not the end: the rest of the file is missing
        return n;
    }

private:
    ByteStream in_;
    InputDescription desc_;
    std::vector<XyzColumn> fields_;
    std::string line_;
    std::vector<double> values_;
    bool sawData_ = false;
};

}  // namespace

std::string detectTextLayout(const std::vector<double>& row) {
    auto isByte = [](double v) { return v >= 0 && v <= 255 && v == std::floor(v); };
    switch (row.size()) {
        case 3: return "x,y,z";
        case 4: return "x,y,z,i";
        case 6: return isByte(row[3]) && isByte(row[4]) && isByte(row[5]) ? "x,y,z,r,g,b" : "x,y,z,nx,ny,nz";
        case 7: return "x,y,z,i,r,g,b";
        case 9: return "x,y,z,r,g,b,nx,ny,nz";
        default: return "";
    }
}

Result<std::unique_ptr<PointReader>> openTextReader(const std::string& path, const std::string& layoutArg, const HttpOptions& http) {
    std::string layout = layoutArg;
    if (layout.empty()) {
        // Detect from the first data row, then reopen to stream from the start.
        auto probe = ByteStream::open(path, http);
        if (!probe) return probe.status();
        std::string line;
        std::vector<double> row;
        while (probe->readLine(&line)) {
            if (line.empty() || line[0] == '#') continue;
            if (!splitNumbers(line, &row))
                return Status::error(path + ": line " + std::to_string(probe->line() - 1) + ": not a row of numbers");
            if (row.size() == 1) continue;
            if (!row.empty()) break;
        }
        if (row.empty()) return Status::error(path + ": no data rows");
        layout = detectTextLayout(row);
        if (layout.empty())
            return Status::error(path + ": cannot tell the meaning of " + std::to_string(row.size()) +
                                 " columns; give the layout with --columns (e.g. x,y,z,r,g,b)");
    }
    std::vector<XyzColumn> fields;
    if (!parseLayout(layout, &fields))
        return Status::error("column layout '" + layout + "' is not a comma-separated list of x,y,z,r,g,b,nx,ny,nz,i,_ with x, y and z");
    auto in = ByteStream::open(path, http);
    if (!in) return in.status();
    InputDescription desc;
    desc.path = path;
    desc.format = "text";
    auto has = [&](XyzColumn f) { return std::find(fields.begin(), fields.end(), f) != fields.end(); };
    desc.hasColors = has(R) && has(G) && has(B);
    desc.hasNormals = has(NX) && has(NY) && has(NZ);
    desc.hasIntensity = has(I);
    return std::unique_ptr<PointReader>(new TextReader(std::move(*in), desc, fields));
}

}  // namespace surfcast
