"""GLSL sources of the bone renderer (OpenGL 3.3 core): two ways to draw the same picture.

``THESIS_*``, the thesis's pipeline [7.4]: α of every tet lives in a 2D texture, each tet is one
four-vertex primitive (lines with adjacency), and a geometry shader emits its four faces when
α ≥ the threshold; a frame uploads only the α texture. ``FACES_*``: only the faces on the
remaining bone's boundary, found on the CPU, drawn as plain triangles. Both share the fragment
shader: a flat normal from screen-space derivatives (so both light a triangle alike, whichever
way it was wound), two-sided Lambert light from the camera, and the α colour map from a
256-texel lookup texture.
"""

FRAGMENT = """
#version 330
in vec3 g_world;
flat in float g_alpha;
uniform sampler2D colour_map;
uniform vec3 light_direction;
uniform float alpha_low;
out vec4 colour;
void main() {
    vec3 normal = normalize(cross(dFdx(g_world), dFdy(g_world)));
    float light = 0.35 + 0.65 * abs(dot(normal, light_direction));
    float u = clamp((g_alpha - alpha_low) / (1.0 - alpha_low), 0.0, 1.0);
    vec3 base = texture(colour_map, vec2((u * 255.0 + 0.5) / 256.0, 0.5)).rgb;
    colour = vec4(base * light, 1.0);
}
"""

FACES_VERTEX = """
#version 330
in vec3 in_position;
in float in_alpha;
uniform mat4 mvp;
out vec3 g_world;
flat out float g_alpha;
void main() {
    g_world = in_position;
    g_alpha = in_alpha;
    gl_Position = mvp * vec4(in_position, 1.0);
}
"""

THESIS_VERTEX = """
#version 330
in vec3 in_position;
out vec3 v_position;
void main() {
    v_position = in_position;
}
"""

THESIS_GEOMETRY = """
#version 330
layout(lines_adjacency) in;
layout(triangle_strip, max_vertices = 12) out;
in vec3 v_position[];
uniform sampler2D alpha_texture;
uniform int alpha_width;
uniform float threshold;
uniform mat4 mvp;
out vec3 g_world;
flat out float g_alpha;
// outward faces of a positively oriented tet, opposite vertex 0, 1, 2, 3
const ivec3 FACES[4] = ivec3[4](ivec3(1, 2, 3), ivec3(0, 3, 2), ivec3(0, 1, 3), ivec3(0, 2, 1));
void main() {
    // the primitive's number is the tet's: its texel holds the tet's α
    int tet = gl_PrimitiveIDIn;
    float alpha = texelFetch(alpha_texture, ivec2(tet % alpha_width, tet / alpha_width), 0).r;
    if (alpha < threshold) {
        return;
    }
    for (int face = 0; face < 4; face++) {
        for (int v = 0; v < 3; v++) {
            vec3 p = v_position[FACES[face][v]];
            g_world = p;
            g_alpha = alpha;
            gl_Position = mvp * vec4(p, 1.0);
            EmitVertex();
        }
        EndPrimitive();
    }
}
"""

REAMER_VERTEX = """
#version 330
in vec3 in_position;
uniform mat4 mvp;
out vec3 g_world;
void main() {
    g_world = in_position;
    gl_Position = mvp * vec4(in_position, 1.0);
}
"""

REAMER_FRAGMENT = """
#version 330
in vec3 g_world;
uniform vec3 light_direction;
uniform vec4 tint;
out vec4 colour;
void main() {
    vec3 normal = normalize(cross(dFdx(g_world), dFdy(g_world)));
    float light = 0.5 + 0.5 * abs(dot(normal, light_direction));
    colour = vec4(tint.rgb * light, tint.a);
}
"""
