/* The braided style: hair combed flat over the scalp into one plait at the
 * nape or two behind the ears (the seed picks), each a three-strand plait
 * hanging from its gathering point.
 *
 * What it gives a training set that the other styles do not: many layers of
 * strands lying almost parallel on the scalp (the comb presses them within
 * 0.3-2% of the head's radius of it, where the other styles' layers reach
 * 12%), so a pixel's fragment list is deep and its highlights are streaks
 * along the strands; and the plait, whose three bundles cross each other
 * every third of a period, strands of one bundle occluding the others'.
 *
 * The hair is parted as a plait is made: each plait's hair in three
 * sections of the scalp (one plait: left, middle and right of the head;
 * two: front, middle and back of each side), each section one bundle. A
 * bundle k of the plait follows, at distance u down the plait's centre
 * line, the classic three-strand parametrisation with theta = 2 pi u /
 * period + 2 pi k / 3:
 *     side offset  A sin(theta),   depth offset  A/2 sin(2 theta),
 * (A = curl_radius, period = curl_period), where two bundles at the same
 * side offset are always at opposite depths, so the bundles weave without
 * passing through each other. A strand keeps its own offset in its bundle
 * (a disc of 0.55 A, at least 0.02), and the plait narrows towards its end.
 *
 * gather (0..1) draws the strands together at the gathering point: every
 * offset there, the bundle's and the strand's own, is scaled by 1 - gather
 * and grows back to its full size over half a period down the plait. At 1
 * every strand of a plait passes through one point, as when a model's
 * strands are aimed at one point or an elastic ties them tight: the
 * deepest fragment lists hair gives, thousands of strands in a pixel. */
#include <math.h>
#include <string.h>

#include "hfrender.h"
#include "hr_math.h"
#include "hr_style.h"

static const float head_r[3] = HFR_HEAD_RADII;

int hr_braid_plaits(const hfr_style_params *sp) {
  /* From the seed alone, so that every strand of a model agrees. */
  hr_rng g = {sp->seed * 0xbf58476d1ce4e5b9ull + 0x5851f42d4c957f2dull};
  return 1 + (int)(hr_rng_next(&g) >> 63);
}

int hr_braid_section(int plaits, const float root[3]) {
  if (plaits == 1) return root[0] < -0.2f ? 0 : root[0] > 0.2f ? 2 : 1;
  int side = root[0] < 0 ? 0 : 3;
  return side + (root[2] > 0.25f ? 0 : root[2] < -0.25f ? 2 : 1);
}

/* The plait of section sec: where it is gathered, the direction it hangs
 * in, and its side and depth axes (orthonormal, the depth axis pointing
 * away from the head). */
static void plait_frame(int plaits, int sec, float gather[3], float down[3], float side[3],
                        float depth[3]) {
  float out[3];
  if (plaits == 1) {
    const float g0[3] = {0, -0.45f, -0.9f}, d0[3] = {0, -1, -0.35f}, o0[3] = {0, 0, -1};
    memcpy(gather, g0, sizeof g0), memcpy(down, d0, sizeof d0), memcpy(out, o0, sizeof o0);
  } else {
    float sx = sec < 3 ? -1.0f : 1.0f;
    const float g1[3] = {0.62f * sx, -0.45f, -0.42f}, d1[3] = {0.15f * sx, -1, -0.1f},
                o1[3] = {sx, 0, 0};
    memcpy(gather, g1, sizeof g1), memcpy(down, d1, sizeof d1), memcpy(out, o1, sizeof o1);
  }
  hr_push_out_of(head_r, gather, 0.03f);
  hr_normalize(down);
  float d = hr_dot(out, down);
  for (int k = 0; k < 3; k++) depth[k] = out[k] - d * down[k];
  hr_normalize(depth);
  hr_cross(down, depth, side);
  hr_normalize(side);
}

void hr_grow_braided(const hfr_style_params *sp, hr_rng *g, const float root[3], float len,
                     float shell, float *c, hr_tie *tie) {
  const int n = sp->segments, plaits = hr_braid_plaits(sp);
  const int sec = hr_braid_section(plaits, root), bundle = sec % 3;
  float gather[3], down[3], side[3], depth[3];
  plait_frame(plaits, sec, gather, down, side, depth);
  const float A = sp->curl_radius, period = sp->curl_period > 0 ? sp->curl_period : 1.0f;
  /* The strand's place in its bundle: uniform over a disc of 0.55 A, at
   * least 0.02 across (a swing of 0 then gives a rope of three bundles on
   * the centre line, not every strand drawn on one curve). */
  float rr = fmaxf(0.55f * A, 0.02f) * sqrtf(hr_rng_uniform(g));
  float ra = 2 * HR_PI * hr_rng_uniform(g);
  const float o_side = rr * cosf(ra), o_depth = rr * sinf(ra);
  const float phase = 2 * HR_PI * (float)bundle / 3;
  const float loose = 1 - sp->gather;
  /* Where the strand joins the plait: its bundle's place at u = 0, drawn
   * in towards the gathering point. */
  float start[3];
  for (int k = 0; k < 3; k++)
    start[k] = gather[k] + loose * (A * sinf(phase) + o_side) * side[k] +
               loose * (0.5f * A * sinf(2 * phase) + o_depth) * depth[k];
  float dt[3] = {start[0] - root[0], start[1] - root[1], start[2] - root[2]};
  float dist = hr_len(dt) * 1.15f;   /* over the scalp, not through it */
  int n1 = (int)(n * dist / len);
  if (n1 < 2) n1 = 2;
  if (n1 > n - 4) n1 = n - 4;
  memcpy(c, root, 3 * sizeof(float));
  /* Combed flat: over the scalp at the strand's small layer offset, which
   * tightens into the gathering point. */
  for (int i = 1; i <= n1; i++) {
    float t = (float)i / n1;
    float *p = c + 3 * i;
    for (int k = 0; k < 3; k++) p[k] = root[k] + (start[k] - root[k]) * t;
    hr_push_out_of(head_r, p, shell * (1 - t) + 0.005f);
  }
  if (tie) {
    tie->index = n1;
    memcpy(tie->point, c + 3 * n1, sizeof tie->point);
  }
  /* The plait: the rest of the strand's length down the centre line. */
  float pl = len - dist;
  if (pl < 0.25f * len) pl = 0.25f * len;
  const float seg = pl / (n - n1);
  for (int i = n1 + 1; i <= n; i++) {
    float u = seg * (i - n1), t = (float)(i - n1) / (n - n1);
    /* Narrows towards the end; near the gathering point, opens from it. */
    float open = fminf(1.0f, u / (0.5f * period));
    float taper = (1 - 0.4f * t * t) * (1 - sp->gather * (1 - open * open * (3 - 2 * open)));
    float th = 2 * HR_PI * u / period + phase;
    float s = taper * (A * sinf(th) + o_side), d = taper * (0.5f * A * sinf(2 * th) + o_depth);
    float *p = c + 3 * i;
    for (int k = 0; k < 3; k++) p[k] = gather[k] + u * down[k] + s * side[k] + d * depth[k];
    hr_push_out_of(head_r, p, 0.02f);
  }
}
