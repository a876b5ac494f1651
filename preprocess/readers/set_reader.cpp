// A tile set's leaves as input points (set_reader.h).
#include "set_reader.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>

#include "http_tile_source.h"
#include "input_file.h"
#include "inputs.h"
#include "object_store.h"
#include "tileset_reader.h"

namespace surfcast {

namespace {

class SetReader final : public PointReader {
public:
    SetReader(TilesetReader set, const std::string& path, const ScalarSelection& scalars) : set_(std::move(set)) {
        const TilesetInfo& info = set_.info();
        desc_.path = path;
        desc_.format = "tileset";
        desc_.hasNormals = true;
        desc_.hasColors = info.colorBits > 0;
        desc_.colorBits = info.colorBits > 0 ? info.colorBits : 8;
        intensity_ = info.attribute(kLidarAttributes[kLidarIntensity]);
        desc_.hasIntensity = intensity_ != nullptr;
        desc_.hasClassification = info.attribute(kLidarAttributes[kLidarClassification]) != nullptr;
        desc_.hasReturns = info.attribute(kLidarAttributes[kLidarReturnNumber]) != nullptr;
        desc_.airborne = info.normalSource == "estimated-up";
        for (size_t i = 0; i < set_.nodes().size(); ++i) {
            const NodeRecord& n = set_.nodes()[i];
            if (!(n.flags & kFlagInputPoints)) continue;
            leaves_.push_back(i);
            desc_.declaredPoints += n.surfelCount;
            desc_.precision = std::max(desc_.precision, std::ldexp(nodeEdge(info, n.key.level), -int(n.positionBits)));
        }
        for (const AttributeInfo& a : info.attributes) {
            if (std::find(std::begin(kFixedAttributes), std::end(kFixedAttributes), a.name) != std::end(kFixedAttributes) ||
                lidarIndex(a.name) >= 0 || a.name == kOpacityAttribute || a.name == kProvenanceAttribute ||
                (a.name.ends_with(kLowPartSuffix) && info.attribute(a.name.substr(0, a.name.size() - std::strlen(kLowPartSuffix)))))
                continue;
            // A wide field is its two parts' sum, at its low part's step (ScalarQuantization).
            const AttributeInfo* low = info.attribute(a.name + kLowPartSuffix);
            if (!scalars.wants(a.name)) {
                desc_.otherScalars.push_back(a.name);
                continue;
            }
            desc_.scalars.push_back({a.name, a.kind == "categorical", low ? low->scale : a.scale});
            fields_.push_back(&a);
            lows_.push_back(low);
        }
        // The set's constants: a value of every point.
        for (const ConstantAttribute& c : info.constants) {
            const int lidar = lidarIndex(c.name);
            if (lidar >= 0) {
                // Within what the attribute holds (a hostile value would make the casts below undefined).
                constantLidar_[lidar] = std::clamp(c.value, 0.0, lidar == kLidarIntensity ? 65535.0 : 255.0);
                (lidar == kLidarIntensity ? desc_.hasIntensity : lidar == kLidarClassification ? desc_.hasClassification : desc_.hasReturns) = true;
            } else if (scalars.wants(c.name)) {
                desc_.scalars.push_back({c.name, false, 0});
                constants_.push_back(c.value);
            } else {
                desc_.otherScalars.push_back(c.name);
            }
        }
        for (const std::string& name : info.leftOut) desc_.otherScalars.push_back(name);
        desc_.las = info.las;
        if (info.las.scale.x > 0) {  // an update's decoded leaves snap to the lattice (InputDescription::latticeScale)
            desc_.latticeScale = info.las.scale;
            desc_.latticeOffset = info.las.offset;
        }
    }

    // Its pointers point into set_: never copied or moved.
    SetReader(const SetReader&) = delete;
    SetReader& operator=(const SetReader&) = delete;

    const InputDescription& description() const override { return desc_; }

    Result<size_t> read(InputPoint* out, size_t max) override {
        scalarValues_.clear();
        size_t n = 0;
        while (n < max) {
            if (at_ == block_.size()) {
                if (next_ == leaves_.size()) break;
                SC_TRY(decodeNext());
                continue;
            }
            const size_t i = at_++;
            InputPoint& p = out[n++];
            p = InputPoint{};
            p.position = set_.position(*node_, block_, i);
            p.normal = Vec3f{block_.normals[3 * i], block_.normals[3 * i + 1], block_.normals[3 * i + 2]};
            // In the 16-bit range, as every reader gives colours (8-bit values times 257).
            if (!block_.colors.empty())
                for (int k = 0; k < 3; ++k) p.color[k] = uint16_t(block_.colors[3 * i + k] * (set_.info().colorBits == 8 ? 257 : 1));
            // Stored as (value - offset) / scale: the value again (the top
            // step's can pass 65535, which a build clamps to the top too).
            p.intensity = uint16_t(std::clamp(intensity_ && !block_.intensity.empty()
                                                  ? std::lround(block_.intensity[i] * intensity_->scale + intensity_->offset)
                                                  : std::lround(constantLidar_[kLidarIntensity]), 0l, 65535l));
            p.classification = block_.classification.empty() ? uint8_t(constantLidar_[kLidarClassification]) : block_.classification[i];
            const int ret = block_.returnNumber.empty() ? int(constantLidar_[kLidarReturnNumber]) : block_.returnNumber[i];
            const int count = block_.numberOfReturns.empty() ? int(constantLidar_[kLidarNumberOfReturns]) : block_.numberOfReturns[i];
            p.returns = uint8_t((ret & 15) | count << 4);
            if (!block_.opacity.empty()) p.alpha = block_.opacity[i];
            for (size_t f = 0; f < fields_.size(); ++f) {
                const int k = scalarIndex_[f], low = lowIndex_[f];
                scalarValues_.push_back(k < 0 ? NAN
                                              : block_.scalars[size_t(k)].values[i] * fields_[f]->scale + fields_[f]->offset +
                                                    (low < 0 ? 0.0 : block_.scalars[size_t(low)].values[i] * lows_[f]->scale));
            }
            scalarValues_.insert(scalarValues_.end(), constants_.begin(), constants_.end());
        }
        return n;
    }

private:
    Status decodeNext() {
        node_ = &set_.nodes()[leaves_[next_++]];
        auto block = set_.readBlock(*node_, !fields_.empty());
        if (!block) return block.status();
        block_ = std::move(*block);
        at_ = 0;
        scalarIndex_.assign(fields_.size(), -1);
        lowIndex_.assign(fields_.size(), -1);
        for (size_t f = 0; f < fields_.size(); ++f)
            for (size_t k = 0; k < block_.scalars.size(); ++k) {
                if (block_.scalars[k].name == fields_[f]->name) scalarIndex_[f] = int(k);
                if (lows_[f] && block_.scalars[k].name == lows_[f]->name) lowIndex_[f] = int(k);
            }
        return {};
    }

    TilesetReader set_;
    InputDescription desc_;
    std::vector<size_t> leaves_;                // indices in set_.nodes() of the input-point nodes
    std::vector<const AttributeInfo*> fields_;  // per stored field of desc_.scalars, in set_.info()
    std::vector<const AttributeInfo*> lows_;    // per field: its low part, or null
    std::vector<double> constants_;             // the constant fields' values, after the stored ones in desc_.scalars
    double constantLidar_[kLidarCount] = {0, 0, 1, 1};  // a LiDAR attribute's value where the set stores none
    const AttributeInfo* intensity_ = nullptr;
    const NodeRecord* node_ = nullptr;
    BlockData block_;
    size_t next_ = 0, at_ = 0;
    std::vector<int> scalarIndex_, lowIndex_;  // per field: its (low part's) index in block_.scalars, or -1
};

}  // namespace

bool isSetInput(const std::string& path) { return std::filesystem::path(path).filename() == "tileset.json"; }

std::string inputName(const std::string& path) {
    const bool url = path.find("://") != std::string::npos;  // its query is not the file's name
    const std::filesystem::path p(url ? path.substr(0, path.find_first_of("?#")) : path);
    return (isSetInput(path) ? p.parent_path().filename() : p.filename()).string();
}

Result<std::unique_ptr<PointReader>> openSetReader(const std::string& path, const ScalarSelection& scalars) {
    if (isS3Url(path)) {  // the set's prefix, through the store's tile source
        auto set = openTileset(path.substr(0, path.size() - std::string("/tileset.json").size()));
        if (!set) return set.status();
        return std::unique_ptr<PointReader>(std::make_unique<SetReader>(std::move(*set), path, scalars));
    }
    if (isRemoteInput(path)) return Status::error(path + ": a tile set is read as an input from a local folder or an s3:// prefix only");
    const std::string folder = std::filesystem::path(path).parent_path().string();
    auto set = TilesetReader::open(folder.empty() ? std::string(".") : folder);
    if (!set) return set.status();
    return std::unique_ptr<PointReader>(std::make_unique<SetReader>(std::move(*set), path, scalars));
}

}  // namespace surfcast
