#version 450
// Translucent frames, last: the layers' premultiplied composite over the
// background. Output alpha is the composite's opacity.
#extension GL_GOOGLE_include_directive : require
#include "splat_common.glsl"

layout(set = 0, binding = 0) uniform sampler2D composite;

layout(location = 0) out vec4 outColor;

void main() {
    vec4 c = texelFetch(composite, ivec2(gl_FragCoord.xy), 0);
    outColor = vec4(c.rgb + (1.0 - c.a) * frameBackground(), c.a);
}
