/* Network definition: Table 1 presets, channel arithmetic, transforms. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "hfcore.h"

static void test_table1_presets(void **state) {
  static const struct { const char *name; int spp, L, c[4]; } want[] = {
    {"Base", 4, 3, {32, 64, 128}},     {"Base@1spp", 1, 3, {32, 64, 128}},
    {"Base@2spp", 2, 3, {32, 64, 128}}, {"Large", 4, 3, {64, 128, 256}},
    {"Small", 4, 3, {16, 32, 64}},     {"Shallow", 4, 2, {32, 64}},
    {"Deep", 4, 4, {32, 64, 128, 256}}};
  /* Table 1 + Residual + Kernel + KernelAC + KernelMix */
  assert_int_equal(hf_variant_preset_count(), 11);
  for (size_t k = 0; k < sizeof want / sizeof want[0]; k++) {
    hf_net_config c;
    assert_int_equal(hf_variant_preset(want[k].name, &c), HF_OK);
    assert_string_equal(c.name, want[k].name);
    assert_int_equal(c.spp, want[k].spp);
    assert_int_equal(c.in_channels, 6 * want[k].spp);
    assert_int_equal(c.out_channels, 3);
    assert_int_equal(c.num_levels, want[k].L);
    for (int i = 0; i < c.num_levels; i++) assert_int_equal(c.levels[i], want[k].c[i]);
    assert_int_equal(c.arch, HF_ARCH_UNET);
    assert_int_equal(hf_net_config_validate(&c), HF_OK);
  }
  hf_net_config c;
  assert_int_equal(hf_variant_preset("base", &c), HF_OK); /* case-insensitive */
  assert_int_equal(hf_variant_preset("Huge", &c), HF_ENOTFOUND);
  assert_int_equal(hf_variant_preset("Residual", &c), HF_OK);
  assert_int_equal(c.arch, HF_ARCH_RESIDUAL);
  assert_int_equal(c.spp, 4);
  assert_int_equal(c.levels[2], 128);
  assert_int_equal(c.kernel_radius, 0);
  assert_int_equal(hf_variant_preset("kernel", &c), HF_OK);
  assert_string_equal(c.name, "Kernel");
  assert_int_equal(c.arch, HF_ARCH_KERNEL);
  assert_int_equal(c.spp, 4);
  assert_int_equal(c.num_levels, 3);
  assert_int_equal(c.levels[0], 32);
  assert_int_equal(c.kernel_radius, 3);
  assert_int_equal(c.kernel_hidden, 32);
  assert_int_equal(c.out_channels, 49 + 3);
  assert_int_equal(hf_net_config_validate(&c), HF_OK);
  assert_int_equal(c.estimate, HF_ESTIMATE_NONE);
  /* KernelAC: Kernel's shape reading the alpha-corrected estimate too. */
  assert_int_equal(hf_variant_preset("KernelAC", &c), HF_OK);
  assert_int_equal(c.arch, HF_ARCH_KERNEL);
  assert_int_equal(c.estimate, HF_ESTIMATE_ALPHA_CORRECTED);
  assert_int_equal(c.in_channels, 4 * 6 + 3);
  assert_int_equal(c.kernel_radius, 3);
  assert_int_equal(c.kernel_hidden, 32);
  assert_int_equal(hf_net_config_validate(&c), HF_OK);
  assert_int_equal(c.kernel_mix, 0);
  assert_int_equal(hf_kernel_sums_of(&c), HF_KSUMS_ESTIMATE);
  c.in_channels = 24;   /* the estimate's channels missing */
  assert_int_equal(hf_net_config_validate(&c), HF_EFORMAT);
  c.in_channels = 27;
  /* KernelMix: KernelAC and one more raw channel, the mix of the two sums. */
  hf_net_config mix;
  assert_int_equal(hf_variant_preset("KernelMix", &mix), HF_OK);
  assert_int_equal(mix.estimate, HF_ESTIMATE_ALPHA_CORRECTED);
  assert_int_equal(mix.kernel_mix, 1);
  assert_int_equal(mix.out_channels, 49 + 3 + 1);
  assert_int_equal(hf_kernel_sums_of(&mix), HF_KSUMS_MIXED);
  assert_int_equal(hf_kernel_sums_floats(HF_KSUMS_MIXED), 6);
  assert_int_equal(hf_net_config_validate(&mix), HF_OK);
  mix.out_channels = 49 + 3;  /* the mixing channel missing */
  assert_int_equal(hf_net_config_validate(&mix), HF_EFORMAT);
  mix.out_channels = 49 + 4, mix.estimate = HF_ESTIMATE_NONE, mix.in_channels = 24;
  assert_int_equal(hf_net_config_validate(&mix), HF_EFORMAT); /* nothing to mix with */
  mix.estimate = HF_ESTIMATE_ALPHA_CORRECTED, mix.in_channels = 27, mix.kernel_mix = 2;
  assert_int_equal(hf_net_config_validate(&mix), HF_EFORMAT);
  c.arch = HF_ARCH_UNET, c.kernel_radius = c.kernel_hidden = 0, c.out_channels = 3;
  assert_int_equal(hf_net_config_validate(&c), HF_EUNSUPPORTED); /* Kernel only */
  assert_string_equal(hf_estimate_name(HF_ESTIMATE_ALPHA_CORRECTED), "alpha_corrected");
  assert_int_equal(hf_estimate_from_name("alpha_corrected"), HF_ESTIMATE_ALPHA_CORRECTED);
  assert_int_equal(hf_estimate_from_name("premultiplied"), HF_ENOTFOUND);
  assert_string_equal(hf_arch_name(HF_ARCH_KERNEL), "kernel");
  assert_int_equal(hf_arch_from_name("kernel"), HF_ARCH_KERNEL);
  assert_int_equal(hf_arch_from_name("Kernel"), HF_ENOTFOUND);
}

/* The per-pixel estimate, and the residual base: the same estimate over the
 * samples of the 5x5 window around a pixel, cut to the frame. */
static void test_residual_base(void **state) {
  float px[24] = {0};
  /* samples 0 and 2 covered: colour 0.5 / 1.5, highlight 0.2 / 0.4 */
  px[0] = 0.5f, px[1] = 0.2f, px[2] = 0.3f;
  px[12] = 1.5f, px[13] = 0.4f, px[14] = 0.9f;
  float b[3];
  hf_st_estimate(px, 4, b);
  assert_float_equal(b[HF_OUT_COLOR], 1.0f, 1e-6);
  assert_float_equal(b[HF_OUT_HIGHLIGHT], 0.3f, 1e-6);
  assert_float_equal(b[HF_OUT_ALPHA], 0.5f, 1e-6);
  float empty[24] = {0};
  hf_st_estimate(empty, 4, b);
  assert_float_equal(b[HF_OUT_COLOR], 1.0f, 0);
  assert_float_equal(b[HF_OUT_ALPHA], 0.0f, 0);

  /* A 7x6 frame in a buffer 8 pixels wide with 26 floats per pixel (padded
   * channels); one covered sample (colour 2, highlight 0.5) at (3, 2), and
   * garbage in the padding column x = 7 that must never be read. */
  enum { FW = 7, FH = 6, PITCH = 8, STRIDE = 26 };
  static float buf[FH * PITCH * STRIDE];
  memset(buf, 0, sizeof buf);
  float *s = buf + ((size_t)2 * PITCH + 3) * STRIDE + 6;   /* sample 1 */
  s[0] = 2.0f, s[1] = 0.5f, s[2] = 0.7f;
  for (int y = 0; y < FH; y++) buf[((size_t)y * PITCH + 7) * STRIDE + 2] = 1.0f;
  hf_input_view v = {buf, FW, FH, PITCH, STRIDE};
  hf_residual_base(&v, 4, 3, 2, b);            /* full 5x5 window: 100 samples */
  assert_float_equal(b[HF_OUT_COLOR], 2.0f, 0);
  assert_float_equal(b[HF_OUT_HIGHLIGHT], 0.5f, 0);
  assert_float_equal(b[HF_OUT_ALPHA], 1.0f / 100, 1e-7);
  hf_residual_base(&v, 4, 5, 4, b);            /* cut at x <= 6, y <= 5: 4x4 = 64 samples */
  assert_float_equal(b[HF_OUT_ALPHA], 1.0f / 64, 1e-7);
  hf_residual_base(&v, 4, 0, 0, b);            /* (3, 2) is 3 columns away: outside */
  assert_float_equal(b[HF_OUT_ALPHA], 0.0f, 0);
  assert_float_equal(b[HF_OUT_COLOR], 1.0f, 0);
  hf_residual_base(&v, 4, 6, 0, b);            /* padding column x = 7 not counted */
  assert_float_equal(b[HF_OUT_ALPHA], 0.0f, 0);

  /* The whole-frame version (separable sums) gives the same values, on
   * random samples with half of them covered. */
  srand(5);
  for (size_t i = 0; i < sizeof buf / sizeof buf[0]; i++)
    buf[i] = (i % STRIDE) % 6 == 2 ? (float)(rand() % 2) * 0.5f : (float)rand() / RAND_MAX;
  float frame[FH * FW * 3], tmp[FH * FW * 3];
  assert_int_equal(hf_residual_base_frame(&v, 4, frame, tmp), HF_OK);
  for (int y = 0; y < FH; y++)
    for (int x = 0; x < FW; x++) {
      hf_residual_base(&v, 4, x, y, b);
      for (int k = 0; k < 3; k++)
        assert_float_equal(frame[(y * FW + x) * 3 + k], b[k], 1e-5f * (1 + fabsf(b[k])));
    }
  hf_input_view none = {buf, 0, FH, PITCH, STRIDE};
  assert_int_equal(hf_residual_base_frame(&none, 4, frame, tmp), HF_EINVAL);
  /* Other windows: radius 0 is the per-pixel estimate, radius 1 pools the
   * 3x3 window cut to the frame (checked against a direct pool of it). */
  assert_int_equal(hf_pooled_estimate_frame(&v, 4, 0, frame, tmp), HF_OK);
  for (int y = 0; y < FH; y++)
    for (int x = 0; x < FW; x++) {
      hf_st_estimate(buf + ((size_t)y * PITCH + x) * STRIDE, 4, b);
      for (int k = 0; k < 3; k++) assert_float_equal(frame[(y * FW + x) * 3 + k], b[k], 1e-6f);
    }
  assert_int_equal(hf_pooled_estimate_frame(&v, 4, 1, frame, tmp), HF_OK);
  for (int y = 0; y < FH; y++)
    for (int x = 0; x < FW; x++) {
      float n = 0, col = 0, hl = 0, all = 0;
      for (int yy = y - 1; yy <= y + 1; yy++)
        for (int xx = x - 1; xx <= x + 1; xx++) {
          if (xx < 0 || yy < 0 || xx >= FW || yy >= FH) continue;
          const float *px = buf + ((size_t)yy * PITCH + xx) * STRIDE;
          for (int k = 0; k < 4; k++, all++)
            if (px[6 * k + 2] > 0) n++, col += px[6 * k], hl += px[6 * k + 1];
        }
      const float *o = frame + (y * FW + x) * 3;
      assert_float_equal(o[HF_OUT_ALPHA], n / all, 1e-6f);
      assert_float_equal(o[HF_OUT_COLOR], n ? col / n : 1.0f, 1e-5f);
      assert_float_equal(o[HF_OUT_HIGHLIGHT], n ? hl / n : 0.0f, 1e-5f);
    }
  assert_int_equal(hf_pooled_estimate_frame(&v, 4, -1, frame, tmp), HF_EINVAL);
  /* Back to the single covered sample at (3, 2). */
  memset(buf, 0, sizeof buf);
  s[0] = 2.0f, s[1] = 0.5f, s[2] = 0.7f;

  hf_net_config c;
  hf_variant_preset("Residual", &c);
  float o[3] = {0.25f, -1.0f, 0.75f};
  hf_output_finish(&c, &v, 3, 2, o);
  assert_float_equal(o[HF_OUT_COLOR], 2.25f, 1e-6);
  assert_float_equal(o[HF_OUT_HIGHLIGHT], 0.0f, 0);        /* clamped */
  assert_float_equal(o[HF_OUT_ALPHA], 0.76f, 1e-6);
  hf_variant_preset("Base", &c);
  float u[3] = {0.0f, 0.5f, 0.5f};
  hf_output_finish(&c, NULL, 0, 0, u); /* the paper's transforms; input unused */
  assert_float_equal(u[HF_OUT_COLOR], 1.0f, 1e-6);
}

/* The Kernel architecture's output stage on frames whose result is known in
 * closed form: equal logits give the box mean of the samples cut to the
 * frame (the pooled estimate), one dominant logit gives that neighbour's own
 * estimate, and taps outside the frame never count, whatever their logits. */
static void test_kernel_output(void **state) {
  enum { FW = 9, FH = 7, PITCH = 11, SPP = 4, STRIDE = SPP * 6, R = 2, TAPS = 25 };
  enum { RAW = TAPS + 3, RAW_STRIDE = RAW + 1 }; /* one unread channel per pixel */
  static float buf[FH * PITCH * STRIDE], raw[FH * PITCH * RAW_STRIDE];
  static float out[FH * FW * 3], sums[FH * FW * 3], want[FH * FW * 3], tmp[FH * FW * 3];
  /* Random samples, 40% uncovered (all zeros); the three left columns
   * empty, so that pixel column 0 sees no covered sample within 2 pixels;
   * the padding columns x >= FW covered and bright, never to be read. */
  srand(17);
  for (int y = 0; y < FH; y++)
    for (int x = 0; x < PITCH; x++)
      for (int k = 0; k < SPP; k++) {
        float *sm = buf + ((size_t)y * PITCH + x) * STRIDE + 6 * k;
        int covered = x >= FW || (x >= 3 && rand() % 5 >= 2);
        for (int f = 0; f < 6; f++) sm[f] = covered ? (float)rand() / RAND_MAX : 0.0f;
        if (covered) sm[2] = 0.05f + sm[2] * 0.95f;
        if (x >= FW) sm[0] = 100.0f;
      }
  hf_input_view v = {buf, FW, FH, PITCH, STRIDE};
  hf_net_config c;
  assert_int_equal(hf_variant_preset("Kernel", &c), HF_OK);
  c.kernel_radius = R, c.kernel_hidden = 0, c.out_channels = RAW;
  assert_int_equal(hf_net_config_validate(&c), HF_OK);

  /* Equal logits (a different constant per pixel), no corrections: the box
   * mean over the window cut to the frame. */
  for (int y = 0; y < FH; y++)
    for (int x = 0; x < PITCH; x++)
      for (int t = 0; t < RAW_STRIDE; t++)
        raw[((size_t)y * PITCH + x) * RAW_STRIDE + t] =
            t < TAPS ? 0.5f * (float)(x + 3 * y) : t == RAW ? NAN : 0.0f;
  assert_int_equal(hf_kernel_output_frame(&v, SPP, HF_ESTIMATE_NONE, R, raw, PITCH, RAW_STRIDE, out, sums), HF_OK);
  assert_int_equal(hf_pooled_estimate_frame(&v, SPP, R, want, tmp), HF_OK);
  for (int i = 0; i < FH * FW * 3; i++)
    assert_float_equal(out[i], want[i], 2e-6f * (1 + fabsf(want[i])));
  /* Column 0 sees only empty samples: colour 1, highlight 0, alpha 0. */
  for (int y = 0; y < FH; y++) {
    assert_float_equal(out[(y * FW) * 3 + HF_OUT_COLOR], 1.0f, 0);
    assert_float_equal(out[(y * FW) * 3 + HF_OUT_HIGHLIGHT], 0.0f, 0);
    assert_float_equal(out[(y * FW) * 3 + HF_OUT_ALPHA], 0.0f, 0);
  }
  /* The bottom-right corner by hand: its window cut to 3x3 pixels. */
  float n = 0, col = 0, hl = 0;
  for (int y = FH - 3; y < FH; y++)
    for (int x = FW - 3; x < FW; x++)
      for (int k = 0; k < SPP; k++) {
        const float *sm = buf + ((size_t)y * PITCH + x) * STRIDE + 6 * k;
        if (sm[2] > 0) n++, col += sm[0], hl += sm[1];
      }
  const float *o = out + ((FH - 1) * FW + FW - 1) * 3;
  assert_true(n > 0);
  assert_float_equal(o[HF_OUT_ALPHA], n / (9 * SPP), 1e-6f);
  assert_float_equal(o[HF_OUT_COLOR], col / n, 1e-5f);
  assert_float_equal(o[HF_OUT_HIGHLIGHT], hl / n, 1e-5f);

  /* One dominant logit, tap (dx, dy) = (2, -1), of 200 (exp(200) overflows
   * a float: the softmax must subtract the maximum); the taps outside the
   * frame get 1e30, and must still count for nothing. Corrections 0.25 on
   * colour, -5 on highlight (clamped to 0) and 0.5 on alpha (clamped to 1). */
  const int DX = 2, DY = -1, TD = (DY + R) * (2 * R + 1) + DX + R;
  for (int y = 0; y < FH; y++)
    for (int x = 0; x < FW; x++) {
      float *rp = raw + ((size_t)y * PITCH + x) * RAW_STRIDE;
      for (int t = 0; t < TAPS; t++) {
        int dx = t % (2 * R + 1) - R, dy = t / (2 * R + 1) - R;
        int inside = x + dx >= 0 && x + dx < FW && y + dy >= 0 && y + dy < FH;
        rp[t] = !inside ? 1e30f : t == TD ? 200.0f : 0.0f;
      }
      rp[TAPS] = 0.25f, rp[TAPS + 1] = -5.0f, rp[TAPS + 2] = 0.5f;
    }
  assert_int_equal(hf_kernel_output_frame(&v, SPP, HF_ESTIMATE_NONE, R, raw, PITCH, RAW_STRIDE, out, sums), HF_OK);
  for (int y = 0; y < FH; y++)
    for (int x = 0; x < FW; x++) {
      float e[3];
      const float *got = out + (y * FW + x) * 3;
      if (x + DX < FW && y + DY >= 0)
        hf_st_estimate(buf + ((size_t)(y + DY) * PITCH + x + DX) * STRIDE, SPP, e);
      else /* the dominant tap is outside: equal weights on the others */
        memcpy(e, want + (y * FW + x) * 3, sizeof e);
      assert_float_equal(got[HF_OUT_COLOR], e[HF_OUT_COLOR] + 0.25f, 1e-5f);
      assert_float_equal(got[HF_OUT_HIGHLIGHT], 0.0f, 0);
      float a = e[HF_OUT_ALPHA] + 0.5f;
      assert_float_equal(got[HF_OUT_ALPHA], a > 1 ? 1.0f : a, 1e-6f);
      /* Pixel by pixel (hf_output_finish) gives the same bits. */
      float px[RAW];
      memcpy(px, raw + ((size_t)y * PITCH + x) * RAW_STRIDE, sizeof px);
      hf_output_finish(&c, &v, x, y, px);
      assert_memory_equal(px, got, 3 * sizeof(float));
    }
  hf_input_view empty = {buf, 0, FH, PITCH, STRIDE};
  assert_int_equal(hf_kernel_output_frame(&empty, SPP, HF_ESTIMATE_NONE, R, raw, PITCH, RAW_STRIDE, out, sums),
                   HF_EINVAL);
  assert_int_equal(hf_kernel_output_frame(&v, SPP, HF_ESTIMATE_NONE, HF_KERNEL_MAX_RADIUS + 1, raw, PITCH,
                                          RAW_STRIDE, out, sums), HF_EINVAL);
}

/* A kernel that mixes (KernelMix): the estimate's sums alone at beta 0 (m
 * very negative), the samples' alone at beta 1, and at beta 1/2 (m = 0) the
 * mean of the two weighted sums, whose alpha is the mean of the two
 * alphas; pixel by pixel (hf_output_finish) gives the same bits. */
static void test_kernel_output_mixed(void **state) {
  (void)state;
  enum { FW = 9, FH = 7, SPP = 4, R = 2, TAPS = 25, RAW = TAPS + 4, STRIDE = SPP * 6 + 3 };
  static float buf[FH * FW * STRIDE], raw[FH * FW * RAW], out[FH * FW * 3], a[FH * FW * 3],
      b[FH * FW * 3], sums[FH * FW * 6];
  srand(7);
  for (int i = 0; i < FH * FW; i++) {
    float *px = buf + (size_t)i * STRIDE;
    for (int k = 0; k < SPP; k++) {
      float *sm = px + 6 * k;
      int covered = rand() % 3 > 0;
      for (int f = 0; f < 6; f++) sm[f] = covered ? (float)rand() / RAND_MAX : 0.0f;
      if (covered) sm[2] = 0.05f + sm[2] * 0.95f;
    }
    px[SPP * 6] = (float)rand() / RAND_MAX;             /* the estimate's colour, */
    px[SPP * 6 + 1] = (float)rand() / RAND_MAX;         /* highlight */
    px[SPP * 6 + 2] = 0.1f + 0.9f * (float)rand() / RAND_MAX; /* and alpha */
    for (int t = 0; t < RAW; t++)
      raw[(size_t)i * RAW + t] = t < TAPS ? (float)rand() / RAND_MAX : 0.0f;
  }
  hf_input_view v = {buf, FW, FH, FW, STRIDE};
  hf_net_config c;
  assert_int_equal(hf_variant_preset("KernelMix", &c), HF_OK);
  c.kernel_radius = R, c.kernel_hidden = 0, c.out_channels = RAW;
  assert_int_equal(hf_net_config_validate(&c), HF_OK);
  static const float ms[] = {-100.0f, 100.0f, 0.0f};
  for (int j = 0; j < 3; j++) {
    for (int i = 0; i < FH * FW; i++) raw[(size_t)i * RAW + TAPS + 3] = ms[j];
    assert_int_equal(hf_kernel_output_frame(&v, SPP, HF_KSUMS_MIXED, R, raw, FW, RAW, out, sums),
                     HF_OK);
    assert_int_equal(hf_kernel_output_frame(&v, SPP, HF_KSUMS_ESTIMATE, R, raw, FW, RAW, a, sums),
                     HF_OK);
    assert_int_equal(hf_kernel_output_frame(&v, SPP, HF_KSUMS_SAMPLES, R, raw, FW, RAW, b, sums),
                     HF_OK);
    for (int i = 0; i < FH * FW * 3; i++) {
      const float want = j == 0 ? a[i] : j == 1 ? b[i] : 0.0f;
      if (j < 2) assert_float_equal(out[i], want, 1e-6f * (1 + fabsf(want)));
    }
    for (int i = 0; i < FH * FW; i++) {
      if (j == 2)
        assert_float_equal(out[i * 3 + HF_OUT_ALPHA],
                           0.5f * (a[i * 3 + HF_OUT_ALPHA] + b[i * 3 + HF_OUT_ALPHA]), 1e-6f);
      float px[RAW];
      memcpy(px, raw + (size_t)i * RAW, sizeof px);
      hf_output_finish(&c, &v, i % FW, i / FW, px);
      assert_memory_equal(px, out + i * 3, 3 * sizeof(float));
    }
  }
  /* The estimate and the samples differ, so the mix is not either. */
  assert_true(fabsf(a[HF_OUT_ALPHA] - b[HF_OUT_ALPHA]) > 1e-3f);
  assert_int_equal(hf_kernel_output_frame(&v, SPP, 3, R, raw, FW, RAW, out, sums), HF_EINVAL);
}

static void test_wiring(void **state) {
  hf_net_config c;
  hf_variant_preset("Base", &c);
  /* enc: 24->32->64->128; dec2: 128->64; dec1: 128->32; dec0: 64->3 */
  assert_int_equal(hf_enc_in(&c, 0), 24);
  assert_int_equal(hf_enc_out(&c, 0), 32);
  assert_int_equal(hf_enc_in(&c, 2), 64);
  assert_int_equal(hf_dec_in(&c, 2), 128);
  assert_int_equal(hf_dec_out(&c, 2), 64);
  assert_int_equal(hf_dec_in(&c, 1), 128);
  assert_int_equal(hf_dec_out(&c, 1), 32);
  assert_int_equal(hf_dec_in(&c, 0), 64);
  assert_int_equal(hf_dec_out(&c, 0), 3);
  assert_int_equal(hf_net_align(&c), 8);
  /* hand count at 8x8: enc0 16px*9*24*32, enc1 4*9*32*64, enc2 1*9*64*128,
   * dec0 16*16*64*3, dec1 4*16*128*32, dec2 1*16*128*64 */
  double want = 16.0 * 9 * 24 * 32 + 4.0 * 9 * 32 * 64 + 9.0 * 64 * 128 + 16.0 * 16 * 64 * 3 +
                4.0 * 16 * 128 * 32 + 16.0 * 128 * 64;
  assert_true(fabs(hf_net_macs(&c, 8, 8) - want) < 1e-6);
  /* Kernel: dec0 gives 32 hidden channels, the head 32 + 24 -> 49 + 3, and
   * the output stage 4 per tap and pixel. */
  hf_variant_preset("Kernel", &c);
  assert_int_equal(hf_dec_in(&c, 0), 64);
  assert_int_equal(hf_dec_out(&c, 0), 32);
  assert_int_equal(hf_dec_out(&c, 1), 32);
  assert_int_equal(hf_head_in(&c), 56);
  assert_int_equal(hf_kernel_taps(c.kernel_radius), 49);
  want += 16.0 * 16 * 64 * (32 - 3) + 64.0 * 56 * 52 + 64.0 * 4 * 49;
  assert_true(fabs(hf_net_macs(&c, 8, 8) - want) < 1e-6);
  /* Without a head dec0 gives the raw channels itself. */
  c.kernel_radius = 2, c.kernel_hidden = 0, c.out_channels = 25 + 3;
  assert_int_equal(hf_net_config_validate(&c), HF_OK);
  assert_int_equal(hf_dec_out(&c, 0), 28);
  assert_int_equal(hf_head_in(&c), 0);
  hf_variant_preset("Residual", &c);
  assert_int_equal(hf_head_in(&c), 0);
}

static void test_validate_rejects(void **state) {
  hf_net_config c;
  hf_variant_preset("Base", &c);
  hf_net_config bad = c;
  bad.spp = 0;
  assert_int_not_equal(hf_net_config_validate(&bad), HF_OK);
  bad = c;
  bad.in_channels = 23;
  assert_int_not_equal(hf_net_config_validate(&bad), HF_OK);
  bad = c;
  bad.num_levels = 0;
  assert_int_not_equal(hf_net_config_validate(&bad), HF_OK);
  bad = c;
  bad.num_levels = HF_MAX_LEVELS + 1;
  assert_int_not_equal(hf_net_config_validate(&bad), HF_OK);
  bad = c;
  bad.levels[1] = 0;
  assert_int_not_equal(hf_net_config_validate(&bad), HF_OK);
  bad = c;
  bad.out_channels = 4;
  assert_int_not_equal(hf_net_config_validate(&bad), HF_OK);
  bad = c;
  bad.arch = 9;
  assert_int_equal(hf_net_config_validate(&bad), HF_EUNSUPPORTED);
  bad = c;
  bad.kernel_radius = 3; /* only for the kernel architecture */
  assert_int_equal(hf_net_config_validate(&bad), HF_EFORMAT);
  hf_variant_preset("Kernel", &c);
  bad = c;
  bad.kernel_radius = 0;
  assert_int_equal(hf_net_config_validate(&bad), HF_ERANGE);
  bad.kernel_radius = HF_KERNEL_MAX_RADIUS + 1;
  assert_int_equal(hf_net_config_validate(&bad), HF_ERANGE);
  bad = c;
  bad.kernel_hidden = -1;
  assert_int_equal(hf_net_config_validate(&bad), HF_ERANGE);
  bad.kernel_hidden = HF_KERNEL_MAX_HIDDEN + 1;
  assert_int_equal(hf_net_config_validate(&bad), HF_ERANGE);
  bad = c;
  bad.kernel_radius = 2; /* out_channels no longer taps + 3 */
  assert_int_equal(hf_net_config_validate(&bad), HF_EFORMAT);
  bad = c;
  bad.out_channels = 3;
  assert_int_equal(hf_net_config_validate(&bad), HF_EFORMAT);
}

static void test_output_transform(void **state) {
  float v[3] = {2.0f, -0.5f, 1.5f};
  hf_output_transform(v);
  assert_float_equal(v[0], 8.0f / 32 + 0.4f + 1.0f, 1e-6);
  assert_float_equal(v[1], 0.0f, 0);
  assert_float_equal(v[2], 1.0f, 0);
  float w[3] = {0.0f, 0.25f, -3.0f};
  hf_output_transform(w);
  assert_float_equal(w[0], 1.0f, 1e-7);
  assert_float_equal(w[1], 0.25f, 0);
  assert_float_equal(w[2], 0.0f, 0);
}

static void test_half_roundtrip(void **state) {
  /* Every finite half converts to float and back unchanged. */
  for (uint32_t h = 0; h < 0x10000; h++) {
    if ((h & 0x7c00) == 0x7c00 && (h & 0x3ff)) continue; /* NaN payloads */
    assert_int_equal(hf_f32_to_f16(hf_f16_to_f32((uint16_t)h)), h);
  }
  assert_int_equal(hf_f32_to_f16(1.0f), 0x3c00);
  assert_int_equal(hf_f32_to_f16(65504.0f), 0x7bff);
  assert_int_equal(hf_f32_to_f16(1e6f), 0x7c00);           /* overflow -> inf */
  assert_int_equal(hf_f32_to_f16(1.0f + 1.0f / 2048), 0x3c00); /* tie to even */
  assert_int_equal(hf_f32_to_f16(5.96e-8f), 0x0001);        /* smallest subnormal */
}

/* Backends without asynchronous runs get them from the common code:
 * submit runs the frame, wait hands back its result in order; prepare is
 * accepted; misuse is refused. */
static void test_submit_wait_prepare(void **state) {
  hf_net_config c;
  hf_variant_preset("Shallow", &c);
  hf_weights *w;
  assert_int_equal(hf_weights_init_random(&c, 9, &w), HF_OK);
  hf_backend *b;
  assert_int_equal(hf_backend_create("cpu-ref", &b, NULL, 0), HF_OK);
  assert_int_equal(hf_backend_host_register(b, w, 16), HF_OK);  /* nothing to pin */
  hf_backend_host_unregister(b, w);
  hf_model *m;
  assert_int_equal(hf_model_create(b, w, &m), HF_OK);
  assert_int_equal(hf_model_prepare(m, 2, 9, 7), HF_OK);
  assert_int_equal(hf_model_overlaps(m), 0);   /* cpu-ref runs inside submit */
  /* cpu-ref checks the input, then runs the network on it: two reads. */
  assert_int_equal(hf_model_reads_input_once(m, w, 16), 0);
  assert_int_equal(hf_model_reads_input_once(NULL, w, 16), 0);
  assert_int_equal(hf_model_prepare(m, 0, 9, 7), HF_EINVAL);
  assert_int_equal(hf_model_prepare(m, 1, 100000, 7), HF_ERANGE);
  enum { W = 9, H = 7, C = 24 };
  float in[2][W * H * C], want[2][W * H * 3], got[2][W * H * 3];
  srand(5);
  for (int f = 0; f < 2; f++)
    for (int i = 0; i < W * H * C; i++) in[f][i] = (float)rand() / RAND_MAX;
  for (int f = 0; f < 2; f++) {
    hf_io io = {1, W, H, in[f], HF_F32, want[f], HF_F32};
    assert_int_equal(hf_model_run(m, &io, NULL), HF_OK);
  }
  hf_timing t;
  assert_int_equal(hf_model_wait(m, &t), HF_EINVAL);   /* nothing pending */
  hf_io io0 = {1, W, H, in[0], HF_F32, got[0], HF_F32}, io1 = io0;
  io1.in = in[1];
  io1.out = got[1];
  assert_int_equal(hf_model_submit(m, &io0), HF_OK);
  assert_int_equal(hf_model_submit(m, &io1), HF_OK);
  assert_int_equal(hf_model_submit(m, &io1), HF_ERANGE);   /* HF_MAX_PENDING */
  assert_int_equal(hf_model_run(m, &io1, NULL), HF_EINVAL); /* not while pending */
  assert_int_equal(hf_model_wait(m, &t), HF_OK);
  assert_memory_equal(got[0], want[0], sizeof want[0]);
  assert_int_equal(hf_model_wait(m, &t), HF_OK);
  assert_memory_equal(got[1], want[1], sizeof want[1]);
  io0.width = 0;
  assert_int_equal(hf_model_submit(m, &io0), HF_EINVAL);
  io0.width = W;
  assert_int_equal(hf_model_submit(m, &io0), HF_OK);   /* destroy waits for it */
  hf_model_destroy(m);
  hf_backend_destroy(b);
  hf_weights_free(w);
}

static void test_backend_selection(void **state) {
  hf_backend *b;
  char why[512];
  assert_int_equal(hf_backend_create("cpu-ref", &b, why, sizeof why), HF_OK);
  assert_string_equal(hf_backend_name(b), "cpu-ref");
  hf_backend_destroy(b);
  assert_int_equal(hf_backend_create("nope", &b, why, sizeof why), HF_ENOTFOUND);
  assert_null(b);
  assert_true(strstr(why, "nope") != NULL);
  /* The message says what there is instead. */
  assert_true(strstr(why, "it has ") != NULL);
  assert_true(strstr(why, "cpu-ref") != NULL);
  assert_true(strstr(why, "or auto") != NULL);
#ifndef HF_HAVE_CUDNN
  /* and how to get the GPU backend a build left out. */
  assert_int_equal(hf_backend_create("cudnn", &b, why, sizeof why), HF_ENOTFOUND);
  assert_true(strstr(why, "HF_WITH_CUDNN") != NULL);
#endif
  assert_int_equal(hf_backend_create("auto", &b, why, sizeof why), HF_OK);
  assert_true(strstr(why, hf_backend_name(b)) != NULL); /* says which it chose */
  /* and, when it is not the GPU's, why not: the device is missing, or this
   * build has no cudnn backend (said as such, not "best available"). */
  if (strcmp(hf_backend_name(b), "cudnn") != 0) {
    assert_true(strstr(why, "cudnn") != NULL);
    assert_null(strstr(why, "best available"));
  }
#ifndef HF_HAVE_CUDNN
  assert_true(strstr(why, "cudnn not in this build") != NULL);
  assert_true(strstr(why, "HF_WITH_CUDNN=ON") != NULL);
#endif
  hf_backend_destroy(b);
}

static void test_run_rejects_bad_io(void **state) {
  hf_net_config c;
  hf_variant_preset("Small", &c);
  hf_weights *w;
  assert_int_equal(hf_weights_init_random(&c, 1, &w), HF_OK);
  hf_backend *b;
  assert_int_equal(hf_backend_create("cpu-ref", &b, NULL, 0), HF_OK);
  hf_model *m;
  assert_int_equal(hf_model_create(b, w, &m), HF_OK);
  float in[24], out[3];
  hf_io io = {.batch = 1, .width = 1, .height = 1, .in = in, .out = out};
  memset(in, 0, sizeof in);
  assert_int_equal(hf_model_run(m, &io, NULL), HF_OK);
  io.width = 0;
  assert_int_equal(hf_model_run(m, &io, NULL), HF_EINVAL);
  io.width = 100000;
  assert_int_equal(hf_model_run(m, &io, NULL), HF_ERANGE);
  io.width = 1;
  io.in = NULL;
  assert_int_equal(hf_model_run(m, &io, NULL), HF_EINVAL);
  io.in = in;
  io.in_dtype = (hf_dtype)7;
  assert_int_equal(hf_model_run(m, &io, NULL), HF_EINVAL);
  hf_model_destroy(m);
  hf_backend_destroy(b);
  hf_weights_free(w);
}

/* Pad-and-crop is the definition for odd sizes: a 13x11 frame must give
 * exactly the top-left 13x11 of the 16x16 frame padded with zeros. */
static void test_pad_and_crop(void **state) {
  hf_net_config c;
  hf_variant_preset("Shallow", &c); /* align 4 */
  hf_weights *w;
  assert_int_equal(hf_weights_init_random(&c, 7, &w), HF_OK);
  hf_backend *b;
  assert_int_equal(hf_backend_create("cpu-ref", &b, NULL, 0), HF_OK);
  hf_model *m;
  assert_int_equal(hf_model_create(b, w, &m), HF_OK);
  int W = 13, H = 11, PW = 16, PH = 12, C = 24;
  float *small = calloc((size_t)W * H * C, 4), *big = calloc((size_t)PW * PH * C, 4);
  float *os = calloc((size_t)W * H * 3, 4), *ob = calloc((size_t)PW * PH * 3, 4);
  srand(3);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++)
      for (int k = 0; k < C; k++)
        small[(y * W + x) * C + k] = big[(y * PW + x) * C + k] = (float)rand() / RAND_MAX;
  hf_io a = {1, W, H, small, HF_F32, os, HF_F32}, bb = {1, PW, PH, big, HF_F32, ob, HF_F32};
  assert_int_equal(hf_model_run(m, &a, NULL), HF_OK);
  assert_int_equal(hf_model_run(m, &bb, NULL), HF_OK);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++)
      for (int k = 0; k < 3; k++) assert_true(os[(y * W + x) * 3 + k] == ob[(y * PW + x) * 3 + k]);
  free(small), free(big), free(os), free(ob);
  hf_model_destroy(m);
  hf_backend_destroy(b);
  hf_weights_free(w);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_table1_presets),   cmocka_unit_test(test_wiring),
    cmocka_unit_test(test_residual_base),    cmocka_unit_test(test_kernel_output),
    cmocka_unit_test(test_kernel_output_mixed),
    cmocka_unit_test(test_validate_rejects), cmocka_unit_test(test_output_transform),
    cmocka_unit_test(test_half_roundtrip),   cmocka_unit_test(test_backend_selection),
    cmocka_unit_test(test_submit_wait_prepare),
    cmocka_unit_test(test_run_rejects_bad_io), cmocka_unit_test(test_pad_and_crop),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
