"""The out-of-contract rule of protocol/FEATURES.md ("Out-of-contract
values") in numpy, as src/sample_rule.h and src/sanitise.c apply it before
the network sees a frame: training reads a frame as `hairfilter infer`,
`filter` and `eval` filter it, so a value the C library changes is changed
alike here.

Samples are [..., 6] in FEATURES order (color, highlight, alpha, depth,
tangent.x, tangent.y); the alpha-corrected estimate is [..., 3] (color,
highlight, alpha)."""
import numpy as np

LIGHT_MAX = 64.0   # HF_FEATURE_LIGHT_MAX
SAMPLE_LOW = np.array([0.0, 0.0, 0.0, 0.0, -1.0, -1.0], np.float32)
SAMPLE_HIGH = np.array([LIGHT_MAX, LIGHT_MAX, 1.0, 1.0, 1.0, 1.0], np.float32)
ESTIMATE_HIGH = np.array([LIGHT_MAX, LIGHT_MAX, 1.0], np.float32)


def _uncover(a, bad):
    """a with the groups (last axis) where bad holds set to 0."""
    a[bad] = 0.0
    return a


def _clamp(a, low, high):
    """a clamped into [low, high] in place, as the C rule compares: a value
    not below low and not above high (-0.0 beside a bound 0 included) is
    left as it is, bit for bit; np.clip would turn -0.0 into 0.0."""
    np.copyto(a, low, where=a < low)
    np.copyto(a, high, where=a > high)
    return a


def sanitise_samples(feat):
    """(samples after the rule as a new float32 array, mask [...] of the
    samples it changed). feat: [..., 6]. Rule 1: a non-finite feature makes
    the sample uncovered (all 0); rule 2: alpha <= 0 and not all zero
    (alpha negative, or another feature non-zero), uncovered; rule 3: a
    finite feature outside its range is clamped into it (alpha above 1 to
    1). An all-zero sample (-0.0 included) is left alone."""
    x = np.array(feat, np.float32, copy=True)
    with np.errstate(invalid="ignore"):
        nonfinite = ~np.isfinite(x).all(-1)
        zero = (x == 0).all(-1)
        uncovered = ~nonfinite & ~zero & ~(x[..., 2] > 0)
        out = (x < SAMPLE_LOW) | (x > SAMPLE_HIGH)
    changed = nonfinite | uncovered | (~zero & out.any(-1))
    _uncover(x, nonfinite | uncovered)
    _clamp(x, np.broadcast_to(SAMPLE_LOW, x.shape), np.broadcast_to(SAMPLE_HIGH, x.shape))
    return x, changed


def sanitise_estimate(est):
    """(estimate after its rule as a new float32 array, mask of the pixels
    it changed). est: [..., 3]. All three 0 is left alone; a non-finite
    value or alpha <= 0 makes all three 0; color and highlight are clamped
    to [0, 64] and alpha to at most 1."""
    x = np.array(est, np.float32, copy=True)
    with np.errstate(invalid="ignore"):
        zero = (x == 0).all(-1)
        bad = ~zero & (~np.isfinite(x).all(-1) | ~(x[..., 2] > 0))
        out = (x < 0) | (x > ESTIMATE_HIGH)
    changed = bad | (~zero & out.any(-1))
    _uncover(x, bad)
    _clamp(x, np.zeros(x.shape, np.float32), np.broadcast_to(ESTIMATE_HIGH, x.shape))
    return x, changed
