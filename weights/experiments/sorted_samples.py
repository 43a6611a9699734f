"""Kernel networks that read each pixel's samples front to back: before the
U-Net, the spp samples of every pixel are put in order of depth, nearest
first, uncovered ones last (in their slot order). The output stage reads the
samples as they are (its sums do not depend on the order). Training shuffles
the sample slots (dataset.augment), so a network reads them as a set; in
this order its first layer can tell the front strand's sample from those
behind it.

  python3 weights/experiments/sorted_samples.py train ARGS...   # weights/train.py's

No backend runs these networks; eval_rows.py --stage sorted scores them."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import torch  # noqa: E402

import hfnet  # noqa: E402
import patching  # noqa: E402

ALPHA, DEPTH = hfnet.FEATURES.index("alpha"), hfnet.FEATURES.index("depth")


def sort_samples(x, spp):
    """x [n][spp*6 + more][h][w] with each pixel's first spp samples in order
    of depth, nearest first; samples with alpha <= 0 (uncovered) last, in
    their slot order (a stable sort)."""
    n, c, h, w = x.shape
    nf = len(hfnet.FEATURES)
    s = x[:, :spp * nf].reshape(n, spp, nf, h, w)
    key = torch.where(s[:, :, ALPHA] > 0, s[:, :, DEPTH].float(),
                      torch.full_like(s[:, :, DEPTH].float(), float("inf")))
    order = torch.sort(key, dim=1, stable=True).indices                # [n][spp][h][w]
    s = torch.gather(s, 1, order[:, :, None].expand(-1, -1, nf, -1, -1))
    return torch.cat([s.reshape(n, spp * nf, h, w), x[:, spp * nf:]], dim=1)


class SortedNet(patching.ORIGINAL["HairNet"]):
    def raw(self, x):
        return super().raw(sort_samples(x, self.cfg["spp"]))


def install():
    """hfnet builds SortedNet for every variant; train.raw_shuffle, once
    train is imported, sorts too (training does not go through raw)."""
    patching.install(lambda cfg: {}, HairNet=SortedNet)


uninstall = patching.uninstall


def main(argv):
    if len(argv) < 2 or argv[0] != "train":
        sys.exit(__doc__)
    install()
    import train
    shuffle = train.raw_shuffle
    train.raw_shuffle = lambda net, x: shuffle(net, sort_samples(x, net.cfg["spp"]))
    return train.main(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
