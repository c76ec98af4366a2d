#!/usr/bin/env python3
"""Export torchvision's ImageNet VGG-16 convolution weights for `--features vgg16=PATH`.

Usage:  python3 scripts/export_vgg16.py vgg16.safetensors
Needs:  pip install torch torchvision safetensors

Writes the 13 convolutions of `vgg16(weights=IMAGENET1K_V1).features` under torchvision's key
names (`features.N.weight` [out, in, 3, 3], `features.N.bias` [out], float32). The classifier
is not needed and not written. gscodec never ships these weights; this script downloads them
through torchvision (its cache, its licence terms).
"""

import sys

import torch
import torchvision
from safetensors.torch import save_file


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit("usage: export_vgg16.py OUT.safetensors")
    model = torchvision.models.vgg16(weights=torchvision.models.VGG16_Weights.IMAGENET1K_V1)
    tensors = {
        f"features.{name}": t.detach().to(torch.float32).contiguous()
        for name, t in model.features.state_dict().items()
    }
    assert len(tensors) == 26, f"expected 13 conv layers, got {len(tensors) // 2}"
    save_file(tensors, sys.argv[1])
    print(f"wrote {len(tensors)} tensors to {sys.argv[1]}")


if __name__ == "__main__":
    main()
