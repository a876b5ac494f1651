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
    // Translucent frames: the splat stages with SC_LAYERED, and their own passes.
    LayeredSplatQuadVert, LayeredSplatPointVert, LayeredSplatGeom, SplatPeelFrag, SplatLayerFrag, ResolveLayerFrag, CompositeFrag
};

ShaderCode shaderCode(ShaderId id);

}  // namespace surfcast
