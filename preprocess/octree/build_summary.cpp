// The build's report: BuildSummary::text, what surfcast-build prints.
#include <sstream>

#include "octree_builder.h"

namespace surfcast {

const char* textureFilterName(BuildOptions::TextureFilter filter) {
    switch (filter) {
    case BuildOptions::TextureFilter::Nearest: return "nearest";
    case BuildOptions::TextureFilter::Ewa: return "ewa";
    case BuildOptions::TextureFilter::Optimal: return "optimal";
    }
    return "?";
}

std::string BuildSummary::text() const {
    std::ostringstream out;
    out.setf(std::ios::fixed);
    out.precision(2);
    out << "points in: " << inputPoints << " (" << skippedPoints << " skipped: NaN/Inf or no return"
        << (removedOutliers ? "; " + std::to_string(removedOutliers) + " removed as outliers" : "") << ")\n";
    out << "surfels: " << surfels << " in " << nodes << " nodes, " << levels << " levels, " << chunks << " chunks\n";
    for (size_t l = 0; l < surfelsPerLevel.size(); ++l)
        out << "  level " << l << ": " << nodesPerLevel[l] << " nodes, " << surfelsPerLevel[l] << " surfels\n";
    out << "normals: " << normalSource << "; colour: " << (colorBits ? std::to_string(colorBits) + "-bit" : "none")
        << (textureFilter.empty() ? ""
                                  : " (textures: " + textureFilter +
                                        (textureBytes ? ", " + std::to_string((textureBytes + (1 << 20) - 1) >> 20) + " MiB held" : "") +
                                        "; meshes read: " + std::to_string(meshReads) + ")")
        << (textureFit.groups == 0 ? ""
                                   : "; least squares: " + std::to_string(textureFit.groups) + " solves, " +
                                         std::to_string(textureFit.unknowns) + " unknowns, " + std::to_string(textureFit.samples) +
                                         " samples, CG iterations mean " +
                                         std::to_string(double(textureFit.iterations) / double(textureFit.groups)).substr(0, 5) +
                                         " max " + std::to_string(textureFit.maxIterations) + ", largest residual " +
                                         std::to_string(textureFit.maxResidual).substr(0, 8))
        << "; attributes:";
    for (const std::string& a : attributes) out << " " << a;
    out << (attributes.empty() ? " none\n" : "\n");
    out << "bytes: hierarchy " << hierarchyBytes << ", blocks " << blocksBytes << " ("
        << (inputPoints ? double(blocksBytes + hierarchyBytes) / double(inputPoints) : 0) << " per input point)\n";
    out << "time:";
    for (auto& [phase, s] : phaseSeconds) out << " " << phase << " " << s << " s,";
    if (totalSeconds > 0) out << " total " << totalSeconds << " s (" << double(inputPoints) / totalSeconds / 1e6 << " M points/s)";
    out << "\n";
    out << "build steps (thread-seconds):";
    for (auto& [step, s] : stepSeconds) out << " " << step << " " << s << ",";
    out << "\n";
    out << "peak RSS: " << double(peakRss) / double(1 << 20) << " MiB\n";
    return out.str();
}

}  // namespace surfcast
