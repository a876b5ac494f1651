#include "shader_code.h"

#include "fullscreen.vert.h"
#include "opaque.frag.h"
#include "resolve.frag.h"
#include "splat.geom.h"
#include "splat_accumulate.frag.h"
#include "splat_point.vert.h"
#include "splat_quad.vert.h"
#include "splat_visibility.frag.h"
#include "splat_peel.frag.h"
#include "splat_layer.frag.h"
#include "resolve_layer.frag.h"
#include "composite.frag.h"
#include "layered_splat.geom.h"
#include "layered_splat_point.vert.h"
#include "layered_splat_quad.vert.h"

namespace surfcast {

ShaderCode shaderCode(ShaderId id) {
    switch (id) {
#define CODE(id, array) case ShaderId::id: return {array, sizeof(array)};
        CODE(SplatQuadVert, splat_quad_vert) CODE(SplatPointVert, splat_point_vert) CODE(SplatGeom, splat_geom)
        CODE(SplatVisibilityFrag, splat_visibility_frag) CODE(SplatAccumulateFrag, splat_accumulate_frag)
        CODE(OpaqueFrag, opaque_frag) CODE(FullscreenVert, fullscreen_vert) CODE(ResolveFrag, resolve_frag)
        CODE(LayeredSplatQuadVert, layered_splat_quad_vert) CODE(LayeredSplatPointVert, layered_splat_point_vert)
        CODE(LayeredSplatGeom, layered_splat_geom) CODE(SplatPeelFrag, splat_peel_frag) CODE(SplatLayerFrag, splat_layer_frag)
        CODE(ResolveLayerFrag, resolve_layer_frag) CODE(CompositeFrag, composite_frag)
#undef CODE
    }
    return {nullptr, 0};
}

}  // namespace surfcast
