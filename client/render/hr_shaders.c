/* GLSL of the renderer. The common fragment code (hashing, shading, shadow
 * lookup) is pasted in front of each fragment shader by hr_program.c. */
#include "hr_shaders.h"

#define GLSL_VERSION "#version 450 core\n"

/* Hair: one instance per segment, four vertices each, expanded here into
 * a quad one pixel wide, or as wide as the strand where that is wider
 * (rather than GL lines, whose multisampled rasterisation on llvmpipe loses
 * short segments, and rather than a geometry shader, which costs llvmpipe
 * about twice the time). Attributes
 * 0-4 are the segment's first point, 5-9 its second; the instance that
 * would join two strands is culled. Every point carries its strand id (a
 * float, exact below 2^24): the hash includes it so that strands sharing a
 * pixel-sized cell of model space still draw independent coverage. */
const char hr_glsl_hair_vs[] = GLSL_VERSION
"layout(location = 0) in vec3 a_pos0;\n"
"layout(location = 1) in vec3 a_tan0;\n"
"layout(location = 2) in float a_thick0;\n"
"layout(location = 3) in float a_opac0;\n"
"layout(location = 4) in float a_strand0;\n"
"layout(location = 5) in vec3 a_pos1;\n"
"layout(location = 6) in vec3 a_tan1;\n"
"layout(location = 7) in float a_thick1;\n"
"layout(location = 8) in float a_opac1;\n"
"layout(location = 9) in float a_strand1;\n"
"uniform mat4 u_view;\n"
"uniform mat4 u_proj;\n"
"uniform vec2 u_jitter;          /* NDC offset of this pass */\n"
"uniform vec2 u_viewport;        /* the whole frame in pixels */\n"
"uniform float u_px_per_unit;    /* pixels per model unit at eye distance 1 */\n"
"uniform int u_ortho;\n"
"uniform float u_thick_scale;\n"
"out V { vec3 obj; vec3 wtan; vec3 vtan; float alpha; float vdist; flat uint strand; } vo;\n"
"/* Window depth, interpolated as the rasteriser does (hr_glsl_stac_fs). */\n"
"noperspective out float v_window_z;\n"
"void main() {\n"
"  vec4 e0 = u_view * vec4(a_pos0, 1.0), e1 = u_view * vec4(a_pos1, 1.0);\n"
"  vec4 c0 = u_proj * e0, c1 = u_proj * e1;\n"
"  c0.xy += u_jitter * c0.w;\n"
"  c1.xy += u_jitter * c1.w;\n"
"  bool second = gl_VertexID >= 2;\n"
"  vo.obj = second ? a_pos1 : a_pos0;\n"
"  vo.wtan = second ? a_tan1 : a_tan0;\n"
"  vo.vtan = mat3(u_view) * vo.wtan;\n"
"  vo.strand = uint(a_strand0);\n"
"  vec4 e = second ? e1 : e0;\n"
"  float dist = max(-e.z, 1e-6);\n"
"  vo.vdist = dist;\n"
"  /* Area baked into alpha: the strand's width over the pixel footprint. */\n"
"  float px = (second ? a_thick1 : a_thick0) * u_thick_scale * u_px_per_unit /\n"
"             (u_ortho != 0 ? 1.0 : dist);\n"
"  /* A strand wider than a few frames covers all of it as any wider one\n"
"   * does; wider still, its quad's corners lose precision in clipping, or\n"
"   * overflow (a width near float's largest, or one times --thickness-scale):\n"
"   * such strands were dropped. */\n"
"  px = min(px, 4.0 * max(u_viewport.x, u_viewport.y));\n"
"  vo.alpha = (second ? a_opac1 : a_opac0) * clamp(px, 0.0, 1.0);\n"
"  if (a_strand0 != a_strand1 || c0.w <= 0.0 || c1.w <= 0.0) {\n"
"    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);   /* outside the clip volume: culled */\n"
"    v_window_z = 1.0;\n"
"    return;\n"
"  }\n"
"  vec2 s0 = c0.xy / c0.w * u_viewport * 0.5, s1 = c1.xy / c1.w * u_viewport * 0.5;\n"
"  vec2 d = s1 - s0;\n"
"  d = length(d) > 1e-6 ? normalize(d) : vec2(1.0, 0.0);\n"
"  /* Half the quad's width each side, in NDC: one pixel for a strand\n"
"   * narrower than a pixel (its width is in alpha), the strand's own width\n"
"   * for a wider one (alpha is then the opacity alone), so the covered area\n"
"   * is the strand's at every width. */\n"
"  vec2 off = vec2(-d.y, d.x) / u_viewport * max(px, 1.0) *\n"
"             ((gl_VertexID & 1) == 0 ? 1.0 : -1.0);\n"
"  vec4 c = second ? c1 : c0;\n"
"  gl_Position = vec4(c.xy + off * c.w, c.zw);\n"
"  v_window_z = c.z / c.w * 0.5 + 0.5;\n"
"}\n";

/* The light and the stochastic shadow map lookup (hair and occluder). */
#define FS_LIGHT                                                                \
"uniform vec3 u_light;          /* position, or direction towards the light */\n" \
"uniform int u_light_directional;\n"                                            \
"uniform int u_shadow_on;\n"                                                    \
"uniform sampler2DShadow u_shadow;\n"                                           \
"uniform mat4 u_light_view, u_light_vp;\n"                                      \
"uniform float u_shadow_near, u_shadow_far, u_shadow_bias, u_shadow_texel;\n"   \
"float shadow_visibility(vec3 p) {\n"                                           \
"  if (u_shadow_on == 0) return 1.0;\n"                                         \
"  vec4 c = u_light_vp * vec4(p, 1.0);\n"                                       \
"  vec2 uv = c.xy / c.w * 0.5 + 0.5;\n"                                         \
"  if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return 1.0;\n" \
"  float d = -(u_light_view * vec4(p, 1.0)).z;\n"                               \
"  float ref = (d - u_shadow_near) / (u_shadow_far - u_shadow_near) - u_shadow_bias;\n" \
"  /* Four bilinear comparisons half a texel apart: a 3x3-texel PCF footprint\n" \
"   * that smooths the 1-sample stochastic map. */\n"                          \
"  float s = 0.0;\n"                                                            \
"  for (int y = 0; y < 2; y++)\n"                                               \
"    for (int x = 0; x < 2; x++)\n"                                             \
"      s += texture(u_shadow, vec3(uv + (vec2(x, y) - 0.5) * u_shadow_texel, ref));\n" \
"  return s * 0.25;\n"                                                          \
"}\n"

/* Shared fragment code: hash, hashed alpha threshold, shading, shadows. */
#define FS_COMMON                                                               \
"in V { vec3 obj; vec3 wtan; vec3 vtan; float alpha; float vdist; flat uint strand; } vi;\n" \
"uniform uint u_seed;\n"                                                        \
"uniform float u_hash_scale;\n"                                                 \
"uniform float u_depth_near, u_depth_far;\n"                                    \
FS_LIGHT                                                                        \
"uniform vec3 u_eye;\n"                                                         \
"uniform float u_alpha_r, u_alpha_trt, u_ambient;\n"                            \
"uniform int u_spec_half;\n"                                                    \
"uvec3 pcg3d(uvec3 v) {\n"                                                      \
"  v = v * 1664525u + 1013904223u;\n"                                           \
"  v.x += v.y * v.z; v.y += v.z * v.x; v.z += v.x * v.y;\n"                     \
"  v ^= v >> 16u;\n"                                                            \
"  v.x += v.y * v.z; v.y += v.z * v.x; v.z += v.x * v.y;\n"                     \
"  return v;\n"                                                                 \
"}\n"                                                                           \
"/* The per-cell part of the hash: cell, strand and seed. */\n"               \
"uvec3 hash_cell(vec3 cell) {\n"                                                \
"  return pcg3d(floatBitsToUint(cell) + uvec3(vi.strand * 0x9E3779B9u, u_seed * 0xC2B2AE35u, 1u));\n" \
"}\n"                                                                           \
"float hash01(uvec3 cell, uint salt) {\n"                                       \
"  uvec3 v = pcg3d(cell + uvec3(salt * 0x85EBCA6Bu, 0u, 0u));\n"                \
"  return float(v.x >> 8) * (1.0 / 16777216.0);\n"                              \
"}\n"                                                                           \
"/* Wyman & McGuire 2017: cells of about one pixel in model space, blended\n"   \
" * between the two nearest power-of-two scales, then the blend's CDF undone\n" \
" * so the threshold stays uniform in [0, 1). l2 = log2 of the pixel scale,\n"  \
" * computed once in uniform control flow; c0, c1 the two cells' hashes. */\n"  \
"void hash_cells(float l2, out uvec3 c0, out uvec3 c1) {\n"                     \
"  c0 = hash_cell(floor(exp2(floor(l2)) * vi.obj));\n"                          \
"  c1 = hash_cell(floor(exp2(ceil(l2)) * vi.obj));\n"                           \
"}\n"                                                                           \
"float hashed_threshold(float l2, uvec3 c0, uvec3 c1, uint salt) {\n"           \
"  float a0 = hash01(c0, salt);\n"                                              \
"  float a1 = hash01(c1, salt);\n"                                              \
"  float lf = fract(l2);\n"                                                     \
"  float x = mix(a0, a1, lf);\n"                                                \
"  float a = min(lf, 1.0 - lf);\n"                                              \
"  float t;\n"                                                                  \
"  if (a < 1e-6) t = x;\n"                                                      \
"  else if (x < a) t = x * x / (2.0 * a * (1.0 - a));\n"                        \
"  else if (x < 1.0 - a) t = (x - 0.5 * a) / (1.0 - a);\n"                      \
"  else t = 1.0 - (1.0 - x) * (1.0 - x) / (2.0 * a * (1.0 - a));\n"             \
"  return clamp(t, 1e-6, 1.0);\n"                                               \
"}\n"                                                                           \
"/* The fragment's alpha. With multisampling a fragment is shaded once,\n"    \
" * usually at the pixel centre, which for a partly covered pixel can lie\n"   \
" * outside the primitive, where alpha interpolated between two points of\n"   \
" * different width or opacity runs past both (1.06 seen in the feature\n"     \
" * pass): kept to [0, 1] here, as the feature contract requires\n"            \
" * (protocol/FEATURES.md). The single-sampled passes (shadow map, A-buffer)\n" \
" * shade inside the primitive and use it alike. */\n"                         \
"float frag_alpha() {\n"                                                       \
"  return clamp(vi.alpha, 0.0, 1.0);\n"                                          \
"}\n"                                                                           \
"float hash_log2_scale() {\n"                                                   \
"  float m = max(length(dFdx(vi.obj)), length(dFdy(vi.obj)));\n"                \
"  return log2(1.0 / (u_hash_scale * max(m, 1e-12)));\n"                        \
"}\n"                                                                           \
"/* Fig. 3 of the paper: colour factor F_d + F_TRT (+ ambient), highlight F_R. */\n" \
"void shade(out float color, out float highlight) {\n"                          \
"  vec3 T = normalize(vi.wtan);\n"                                              \
"  vec3 L = u_light_directional != 0 ? normalize(u_light) : normalize(u_light - vi.obj);\n" \
"  float a_hl = acos(clamp(dot(T, L), -1.0, 1.0));\n"                           \
"  float fd = sin(a_hl);\n"                                                     \
"  float a_s = a_hl;\n"                                                         \
"  if (u_spec_half != 0) {\n"                                                   \
"    vec3 H = normalize(L + normalize(u_eye - vi.obj));\n"                      \
"    a_s = acos(clamp(dot(T, H), -1.0, 1.0));\n"                                \
"  }\n"                                                                         \
"  float fr = pow(max(sin(a_s + u_alpha_r), 0.0), 250.0);\n"                    \
"  float ftrt = pow(max(sin(a_s + u_alpha_trt), 0.0), 80.0);\n"                 \
"  float vis = shadow_visibility(vi.obj);\n"                                    \
"  color = u_ambient + vis * (fd + ftrt);\n"                                    \
"  highlight = vis * fr;\n"                                                     \
"}\n"                                                                           \
"float depth01() {\n"                                                           \
"  return clamp((vi.vdist - u_depth_near) / (u_depth_far - u_depth_near), 0.0, 1.0);\n" \
"}\n"

/* Each of the u_samples coverage bits is set with probability alpha from
 * its own hashed threshold; gl_SampleMask is written on every path (Mesa
 * requires it once it is written anywhere). Opaque mode keeps the
 * geometric coverage and alpha 1. */
const char hr_glsl_st_fs[] = GLSL_VERSION FS_COMMON
"layout(location = 0) out vec4 o_f0;   /* color, highlight, alpha, depth */\n"
"layout(location = 1) out vec4 o_f1;   /* tangent.x, tangent.y */\n"
"uniform int u_opaque;\n"
"uniform int u_samples;\n"
"void main() {\n"
"  float l2 = hash_log2_scale();\n"
"  int mask = gl_SampleMaskIn[0];\n"
"  float a = frag_alpha();\n"
"  if (u_opaque == 0) {\n"
"    uvec3 c0, c1;\n"
"    hash_cells(l2, c0, c1);\n"
"    int m = 0;\n"
"    for (int s = 0; s < u_samples; s++)\n"
"      if (hashed_threshold(l2, c0, c1, uint(s)) < a) m |= 1 << s;\n"
"    mask &= m;\n"
"  }\n"
"  gl_SampleMask[0] = mask;\n"
"  /* Most fragments of fine hair keep no sample: skip their shading (and\n"
"   * its shadow lookups) once the whole block has none. */\n"
"  if (mask == 0) discard;\n"
"  float c, h;\n"
"  shade(c, h);\n"
"  vec3 t = normalize(vi.vtan);\n"
"  o_f0 = vec4(c, h, u_opaque != 0 ? 1.0 : a, depth01());\n"
"  o_f1 = vec4(t.xy, 0.0, 0.0);\n"
"}\n";

/* Alpha-corrected stochastic transparency (Enderton et al. 2010, section 3.3,
 * "Stochastic Transparency"), drawn with 4x MSAA so that each fragment
 * reaches the samples it covers: every hair fragment, none hiding another,
 * adds its colour factor and highlight weighted by its alpha and by its
 * visibility, and that weight (RGB, additive); the alpha channel is
 * multiplied by 1 - alpha (the blend the host sets), leaving each sample's
 * exact transmittance. The visibility is the share of the stochastic depth
 * samples (u_depth, the feature pass's) at or behind the fragment among
 * the samples it covers: each is an unbiased estimate of the transmittance
 * in front of it there, where the whole pixel's share would weigh a strand
 * by the samples a neighbour covers (wide strands, edges). Each sample's
 * depth is compared with the fragment's own depth at that sample
 * (v_window_z interpolated there, as the rasteriser does), so a fragment
 * does not hide itself without a bias that would let the strands just
 * behind it through (a slope-scaled one cost 2.3 dB on dense fur). */
const char hr_glsl_stac_fs[] = GLSL_VERSION FS_COMMON
"layout(location = 0) out vec4 o;\n"
"uniform sampler2DMS u_depth;\n"
"uniform int u_samples;\n"
"noperspective in float v_window_z;\n"
"void main() {\n"
"  ivec2 p = ivec2(gl_FragCoord.xy);\n"
"  int n = 0, m = 0;\n"
"  for (int s = 0; s < u_samples; s++)\n"
"    if ((gl_SampleMaskIn[0] & (1 << s)) != 0) {\n"
"      m++;\n"
"      float z = interpolateAtSample(v_window_z, s);\n"
"      if (texelFetch(u_depth, p, s).r >= z * (1.0 - 1e-6)) n++;\n"
"    }\n"
"  float vis = m > 0 ? float(n) / float(m) : 1.0;\n"
"  float c, h;\n"
"  shade(c, h);\n"
"  float a = frag_alpha();\n"
"  o = vec4(c * a * vis, h * a * vis, a * vis, a);\n"
"}\n";

/* The alpha-corrected estimate of the window's pixel (gl_FragCoord +
 * u_origin) from hr_glsl_stac_fs's samples of u_src: each sample's alpha
 * is one less its transmittance and its colour factor and highlight its
 * weighted sums over its summed weight, so that only fragments sharing a
 * sample weigh each other. Means over the samples: (alpha colour, alpha
 * highlight, alpha of the samples with a weight, alpha), premultiplied;
 * the host divides by the third. */
const char hr_glsl_resolve_stac_fs[] = GLSL_VERSION
"uniform sampler2DMS u_src;\n"
"uniform int u_samples;\n"
"uniform ivec2 u_origin;\n"
"out vec4 o;\n"
"void main() {\n"
"  ivec2 p = ivec2(gl_FragCoord.xy) + u_origin;\n"
"  vec4 m = vec4(0.0);\n"
"  for (int i = 0; i < u_samples; i++) {\n"
"    vec4 q = texelFetch(u_src, p, i);\n"
"    float a = clamp(1.0 - q.a, 0.0, 1.0);\n"
"    if (q.b > 0.0) m.xyz += a * vec3(q.r / q.b, q.g / q.b, 1.0);\n"
"    m.w += a;\n"
"  }\n"
"  o = m / float(u_samples);\n"
"}\n";

/* One sample per texel: the strand survives where its hashed threshold is
 * below alpha (salt 255: independent of the camera samples' bits). */
const char hr_glsl_shadow_fs[] = GLSL_VERSION FS_COMMON
"void main() {\n"
"  float l2 = hash_log2_scale();\n"
"  uvec3 c0, c1;\n"
"  hash_cells(l2, c0, c1);\n"
"  bool keep = hashed_threshold(l2, c0, c1, 255u) < frag_alpha();\n"
"  gl_FragDepth = depth01();\n"
"  if (!keep) discard;\n"
"}\n";

/* The ground truth's transmittance cull (hr_gt_cull.c), over the pixels
 * [u_win_lo, u_win_hi) of the supersampled frame (a strip of the window;
 * u_width its width), with the A-buffer's depth test (the occluder).
 * cull_counts holds 17 words a pixel: the fragments of bin k in word k,
 * and in word 16 every fragment. */
#define CULL_COMMON                                                             \
"layout(std430, binding = 4) buffer CullNear { uint cull_near[]; };\n"         \
"layout(std430, binding = 5) buffer CullSums { uint cull_sums[]; };\n"         \
"layout(std430, binding = 6) buffer CullCounts { uint cull_counts[]; };\n"     \
"uniform ivec2 u_win_lo, u_win_hi;\n"                                          \
"uniform int u_width;\n"                                                       \
"/* The pixel's index in the strip, -1 outside it. */\n"                      \
"int cull_pixel() {\n"                                                         \
"  ivec2 q = ivec2(gl_FragCoord.xy);\n"                                        \
"  if (any(lessThan(q, u_win_lo)) || any(greaterThanEqual(q, u_win_hi))) return -1;\n" \
"  q -= u_win_lo;\n"                                                           \
"  return q.y * u_width + q.x;\n"                                              \
"}\n"

/* Step 1: each pixel's nearest hair fragment, as the bits of its view
 * distance (positive floats order as their bits do), and its fragments. */
const char hr_glsl_gt_near_fs[] = GLSL_VERSION
"layout(early_fragment_tests) in;\n"
"in V { vec3 obj; vec3 wtan; vec3 vtan; float alpha; float vdist; flat uint strand; } vi;\n"
CULL_COMMON
"void main() {\n"
"  int i = cull_pixel();\n"
"  if (i < 0) return;\n"
"  atomicMin(cull_near[i], floatBitsToUint(vi.vdist));\n"
"  atomicAdd(cull_counts[17 * i + 16], 1u);\n"
"}\n";

/* Step 2: each fragment's optical depth -ln(1 - alpha), capped at 16 (an
 * alpha of 1 is infinite), in fixed point (4096 to the unit, truncated: a
 * sum never exceeds the true one), added to the first of 16 bins it lies
 * in front of: view distance past the pixel's nearest fragment below
 * u_edge times 2^(k/2), k = 0 .. 15; none past the last. Each bin also
 * counts its fragments. */
const char hr_glsl_gt_depths_fs[] = GLSL_VERSION
"layout(early_fragment_tests) in;\n"
FS_COMMON CULL_COMMON
"uniform float u_edge;\n"
"void main() {\n"
"  int i = cull_pixel();\n"
"  if (i < 0) return;\n"
"  float rel = vi.vdist - uintBitsToFloat(cull_near[i]);\n"
"  int k = 0;\n"
"  while (k < 16 && !(rel < u_edge * exp2(0.5 * float(k)))) k++;\n"
"  if (k == 16) return;\n"
"  float a = frag_alpha();\n"
"  float od = a >= 1.0 ? 16.0 : min(-log(1.0 - a), 16.0);\n"
"  atomicAdd(cull_sums[16 * i + k], uint(od * 4096.0));\n"
"  atomicAdd(cull_counts[17 * i + k], 1u);\n"
"}\n";

/* Step 3, a full-frame pass over the A-buffer's depth (LESS): at each
 * pixel of the strip, the first bound k (of 0 .. 14) whose bins sum to
 * u_tau (fixed point) or more, plus u_margin, as a window depth (z_ndc =
 * u_p14 / d - u_p10), so that the A-buffer's early depth test keeps out
 * what lies behind it. Nothing is written where no bound reaches u_tau or
 * where the bound leaves [u_near_lim, u_far_lim), the depth feature's
 * range (depth01 would clamp there and order equal depths by index). Word
 * 0 of the pixel's counts becomes how many fragments the A-buffer will
 * hold there at most: those of bins 0 .. k + 1 (the margin lies inside bin
 * k + 1), or all of them (word 16) where nothing is cut. The margin is at
 * least 1e-5 of the distance, far above float rounding however far the
 * camera stands. */
const char hr_glsl_gt_cut_fs[] = GLSL_VERSION
CULL_COMMON
"uniform uint u_tau;\n"
"uniform float u_p10, u_p14, u_edge, u_margin, u_near_lim, u_far_lim;\n"
"uint bin_count(int i, int k) { return cull_counts[17 * i + k]; }\n"
"void main() {\n"
"  int i = cull_pixel();\n"
"  if (i < 0) discard;\n"
"  uint nb = cull_near[i], total = cull_counts[17 * i + 16];\n"
"  uint cum = 0u, kept = 0u;\n"
"  int k = 0;\n"
"  for (; k < 15; k++) {\n"
"    uint c = cum + cull_sums[16 * i + k];\n"
"    cum = c < cum ? 0xFFFFFFFFu : c;\n"
"    kept = min(kept + bin_count(i, k), total);\n"
"    if (cum >= u_tau) break;\n"
"  }\n"
"  float dn = uintBitsToFloat(nb);\n"
"  float dc = dn + u_edge * exp2(0.5 * float(min(k, 14))) + max(u_margin, 1e-5 * dn);\n"
"  bool cut = nb != 0xFFFFFFFFu && k < 15 && dn >= u_near_lim && dc < u_far_lim;\n"
"  if (cut) kept = min(kept + bin_count(i, k + 1), total);\n"
"  cull_counts[17 * i] = cut ? kept : total;\n"
"  if (!cut) discard;\n"
"  gl_FragDepth = clamp((u_p14 / dc - u_p10) * 0.5 + 0.5, 0.0, 1.0);\n"
"}\n";

const char hr_glsl_abuf_fs[] = GLSL_VERSION FS_COMMON
"layout(early_fragment_tests) in;   /* the head's depth culls before insertion */\n"
"struct Node { float c, h, a, d; uint next; };\n"
"layout(std430, binding = 0) buffer Heads { uint heads[]; };\n"
"layout(std430, binding = 1) buffer Nodes { Node nodes[]; };\n"
"layout(binding = 0, offset = 0) uniform atomic_uint u_count;\n"
"layout(binding = 0, offset = 4) uniform atomic_uint u_wraps;  /* u_count went round */\n"
"uniform uint u_capacity;\n"
"uniform int u_width;              /* the window's width: heads are the window's */\n"
"uniform ivec2 u_win_lo, u_win_hi;  /* the window (band), supersampled pixels [lo, hi) */\n"
"void main() {\n"
"  /* The scissor is grown to whole 16x16 blocks (hr_set_viewport), so the\n"
"   * window's own pixels are kept here: a band of rows would otherwise\n"
"   * count and store its neighbours' fragments too. */\n"
"  ivec2 q = ivec2(gl_FragCoord.xy);\n"
"  if (any(lessThan(q, u_win_lo)) || any(greaterThanEqual(q, u_win_hi))) return;\n"
"  uint i = atomicCounterIncrement(u_count);\n"
"  if (i == 0xFFFFFFFFu) atomicCounterIncrement(u_wraps);   /* 2^32 more */\n"
"  if (i >= u_capacity) return;   /* counted: the host grows the pool and redraws */\n"
"  float c, h;\n"
"  shade(c, h);\n"
"  nodes[i].c = c; nodes[i].h = h; nodes[i].a = frag_alpha(); nodes[i].d = depth01();\n"
"  ivec2 p = ivec2(gl_FragCoord.xy) - u_win_lo;\n"
"  nodes[i].next = atomicExchange(heads[p.y * u_width + p.x], i);\n"
"}\n";

/* The occluder: position and normal per vertex. */
const char hr_glsl_head_vs[] = GLSL_VERSION
"layout(location = 0) in vec3 a_pos;\n"
"layout(location = 1) in vec3 a_nrm;\n"
"uniform mat4 u_view, u_proj;\n"
"uniform vec2 u_jitter;\n"
"out float v_vdist;\n"
"out vec3 v_pos, v_nrm;\n"
"void main() {\n"
"  vec4 e = u_view * vec4(a_pos, 1.0);\n"
"  vec4 c = u_proj * e;\n"
"  c.xy += u_jitter * c.w;\n"
"  gl_Position = c;\n"
"  v_vdist = -e.z;\n"
"  v_pos = a_pos;\n"
"  v_nrm = a_nrm;\n"
"}\n";

/* In the shadow pass depth is the same linear measure the hair writes. */
const char hr_glsl_head_fs[] = GLSL_VERSION
"in float v_vdist;\n"
"uniform int u_linear_depth;\n"
"uniform float u_depth_near, u_depth_far;\n"
"void main() {\n"
"  gl_FragDepth = u_linear_depth != 0\n"
"      ? clamp((v_vdist - u_depth_near) / (u_depth_far - u_depth_near), 0.0, 1.0)\n"
"      : gl_FragCoord.z;\n"
"}\n";

/* The occluder in the background layer: diffuse (a fifth ambient), lit by
 * the hair's light and shadowed by the hair through the shadow map (looked
 * up a little off the surface, so the occluder does not shadow itself);
 * coverage in alpha. The host multiplies by albedo and light colour. */
const char hr_glsl_occluder_fs[] = GLSL_VERSION
FS_LIGHT
"in float v_vdist;\n"
"in vec3 v_pos, v_nrm;\n"
"uniform float u_normal_offset;\n"
"out vec4 o;\n"
"void main() {\n"
"  vec3 n = length(v_nrm) > 0.0 ? normalize(v_nrm) : vec3(0.0, 1.0, 0.0);\n"
"  vec3 L = u_light_directional != 0 ? normalize(u_light) : normalize(u_light - v_pos);\n"
"  float ndl = max(dot(n, L), 0.0);\n"
"  float vis = ndl > 0.0 ? shadow_visibility(v_pos + n * u_normal_offset) : 0.0;\n"
"  o = vec4(0.2 + 0.8 * ndl * vis, 0.0, 0.0, 1.0);\n"
"}\n";

/* One triangle that covers the framebuffer without being clipped: the
 * viewport is set to twice the target size and the triangle spans its lower
 * left half. (A clipped full-screen triangle makes llvmpipe blend some
 * pixels of partially covered 4x4 blocks wrongly in the A-buffer resolve.) */
const char hr_glsl_fullscreen_vs[] = GLSL_VERSION
"uniform int u_grow;   /* 1: w x h viewport, the usual clipped triangle */\n"
"void main() {\n"
"  vec2 p = vec2(gl_VertexID == 1 ? 1.0 : -1.0, gl_VertexID == 2 ? 1.0 : -1.0);\n"
"  if (u_grow != 0) p = 2.0 * p + 1.0;\n"
"  gl_Position = vec4(p, 0.0, 1.0);\n"
"}\n";

/* Reads every sample (texelFetch on the MS attachments) into an RG32F
 * target 3W x (H * u_samples): texel (3x + j, u_samples * y + s) holds
 * features 2j, 2j + 1 of sample s of pixel (x, y). The host reorders rows
 * into the core's [h][w][samples][6]. */
const char hr_glsl_resolve_ms_fs[] = GLSL_VERSION
"uniform sampler2DMS u_f0, u_f1;\n"
"uniform int u_samples;\n"
"uniform ivec2 u_origin;   /* the window's origin in the frame */\n"
"out vec2 o;\n"
"void main() {\n"
"  ivec2 p = ivec2(gl_FragCoord.xy);\n"
"  int x = p.x / 3, j = p.x - 3 * x;\n"
"  int y = p.y / u_samples, s = p.y - u_samples * y;\n"
"  vec4 a = texelFetch(u_f0, ivec2(x, y) + u_origin, s);\n"
"  vec4 b = texelFetch(u_f1, ivec2(x, y) + u_origin, s);\n"
"  o = j == 0 ? a.xy : (j == 1 ? a.zw : b.xy);\n"
"}\n";

/* Sorts one subsample's list front to back and blends it, exactly: in
 * rounds, each walking the list for the next HR_ABUF_SORT nearest fragments
 * after the last one blended (order: depth, then node index, so ties
 * resolve the same way on the host). Lists longer than one round are
 * counted in Stats.truncated (informative only).
 *
 * One draw per subsample (u_sub), summed by additive blending, because
 * llvmpipe caps the loop iterations of one shader invocation (all loops
 * together, per 4x4 block) at 65535 and silently leaves the loop after
 * that; a whole 4x4 supersampled pixel in one invocation went past it on
 * dense hair. Iterations are still counted, and an invocation that would
 * come near the cap stops and is reported (Stats.overflow): the host then
 * fails rather than return a wrong image. Output is premultiplied
 * (colour * alpha, highlight * alpha, alpha) / s^2. */
#define STR_(x) #x
#define STR(x) STR_(x)
const char hr_glsl_resolve_abuf_fs[] = GLSL_VERSION
"#define K " STR(HR_ABUF_SORT) "\n"
"#define BUDGET 60000u\n"
"struct Node { float c, h, a, d; uint next; };\n"
"layout(std430, binding = 0) readonly buffer Heads { uint heads[]; };\n"
"layout(std430, binding = 1) readonly buffer Nodes { Node nodes[]; };\n"
"layout(std430, binding = 2) buffer Stats { uint max_depth; uint truncated; uint overflow; };\n"
"uniform int u_ss;\n"
"uniform int u_sub;        /* subsample sy * u_ss + sx */\n"
"uniform int u_width;      /* supersampled width of the window: heads are the window's */\n"
"uniform ivec2 u_size;     /* the window's size, pixels */\n"
"uniform uint u_capacity;\n"
"out vec4 o;\n"
"bool before(float da, uint ia, float db, uint ib) { return da < db || (da == db && ia < ib); }\n"
"void main() {\n"
"  ivec2 p = ivec2(gl_FragCoord.xy);   /* in the window */\n"
"  if (p.x >= u_size.x || p.y >= u_size.y) { o = vec4(0.0); return; }  /* block padding */\n"
"  int sy = u_sub / u_ss, sx = u_sub - sy * u_ss;\n"
"  uint idx[K];\n"
"  float dep[K];\n"
"  uint head = heads[(p.y * u_ss + sy) * u_width + p.x * u_ss + sx];\n"
"  uint total = 0u, iters = 0u, rounds = 0u;\n"
"  float T = 1.0, c = 0.0, h = 0.0;\n"
"  float dl = 0.0;       /* last blended fragment (none before round 1) */\n"
"  uint il = 0u;\n"
"  int n = K;\n"
"  bool over = false;\n"
"  while (n == K && !over) {\n"
"    n = 0;\n"
"    uint i = head;\n"
"    while (i != 0xFFFFFFFFu && i < u_capacity && iters < BUDGET) {\n"
"      uint nx = nodes[i].next;\n"
"      float d = nodes[i].d;\n"
"      iters++;\n"
"      if (rounds == 0u) total++;\n"
"      if ((rounds == 0u || before(dl, il, d, i)) &&\n"
"          (n < K || before(d, i, dep[K - 1], idx[K - 1]))) {\n"
"        int k = n < K ? n : K - 1;\n"
"        while (k > 0 && before(d, i, dep[k - 1], idx[k - 1])) {\n"
"          dep[k] = dep[k - 1]; idx[k] = idx[k - 1]; k--;\n"
"          iters++;\n"
"        }\n"
"        dep[k] = d; idx[k] = i;\n"
"        n = min(n + 1, K);\n"
"      }\n"
"      i = nx;\n"
"    }\n"
"    over = i != 0xFFFFFFFFu && i < u_capacity;\n"
"    for (int k = 0; k < n; k++) {\n"
"      Node q = nodes[idx[k]];\n"
"      c += T * q.a * q.c; h += T * q.a * q.h; T *= 1.0 - q.a;\n"
"    }\n"
"    if (n > 0) { dl = dep[n - 1]; il = idx[n - 1]; }\n"
"    rounds++;\n"
"  }\n"
"  if (rounds > 1u && total > uint(K)) atomicAdd(truncated, 1u);\n"
"  if (over) atomicAdd(overflow, 1u);\n"
"  atomicMax(max_depth, total);\n"
"  o = vec4(c, h, 1.0 - T, 0.0) / float(u_ss * u_ss);\n"
"}\n";
