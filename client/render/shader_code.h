// The SPIR-V of client/shaders/, compiled by glslangValidator at build time and
// embedded in the binary (no shader files to find at run time).
#pragma once

#include <cstddef>
#include <cstdint>

namespace surfcast {

struct ShaderCode {
    const uint32_t* code;
    size_t bytes;
};

enum class ShaderId {
    SplatQuadVert, SplatPointVert, SplatGeom, SplatVisibilityFrag, SplatAccumulateFrag, OpaqueFrag, FullscreenVert, ResolveFrag,
    SplatPeelFrag, SplatLayerFrag, ResolveLayerFrag, CompositeFrag  // translucent frames
};

ShaderCode shaderCode(ShaderId id);

}  // namespace surfcast
