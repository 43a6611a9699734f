/* GLSL sources of the renderer's programs (hr_shaders.c). */
#ifndef HR_SHADERS_H
#define HR_SHADERS_H

/* Hair vertex shader, shared by every hair pass: one instance per segment,
 * expanded into a quad max(1, strand width) pixels wide. */
extern const char hr_glsl_hair_vs[];
/* Stochastic-transparency features into the MS attachments. */
extern const char hr_glsl_st_fs[];
/* Stochastic shadow map: hashed alpha test, linear depth. */
extern const char hr_glsl_shadow_fs[];
/* A-buffer insertion. */
extern const char hr_glsl_abuf_fs[];
/* The ground truth's transmittance cull: nearest depth, optical depth
 * sums, cut depth (hr_gt_cull.c). */
extern const char hr_glsl_gt_near_fs[];
extern const char hr_glsl_gt_depths_fs[];
extern const char hr_glsl_gt_cut_fs[];
extern const char hr_glsl_stac_fs[];
/* The occluder: opaque depth (head_fs), and its diffuse shading in the
 * background layer (occluder_fs). */
extern const char hr_glsl_head_vs[];
extern const char hr_glsl_head_fs[];
extern const char hr_glsl_occluder_fs[];
/* Full-viewport triangle and the two resolve passes. */
extern const char hr_glsl_fullscreen_vs[];
extern const char hr_glsl_resolve_ms_fs[];
extern const char hr_glsl_resolve_stac_fs[];
extern const char hr_glsl_resolve_abuf_fs[];

/* Fragments sorted per round of the A-buffer resolve. */
#define HR_ABUF_SORT 64

#endif
