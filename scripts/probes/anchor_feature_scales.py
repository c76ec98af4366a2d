#!/usr/bin/env python3
"""Hyperprior premise probe (docs/codec.md, the anchor profile): do an anchor file's features
have per-anchor scale structure that side information could use?

Decodes FILE.gsc (a 7.0 anchor file) with specdec.py, then compares the empirical entropy of each
feature channel with the entropy when the anchors are split into K equal classes by the mean
magnitude of their features (the class costing its own entropy). No table costs are counted.

    python3 scripts/probes/anchor_feature_scales.py FILE.gsc
"""
import sys

import numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[2] / 'bitstream-spec'))
import specdec
cap={}
orig=specdec.read_block
def rb(rd, channels, rows, what):
    r=orig(rd, channels, rows, what); cap[what]=r[1]; return r
specdec.read_block=rb
specdec.decode(open(sys.argv[1],'rb').read())
y=cap['anchor features']; A,F=y.shape
def H(v):
    _,c=np.unique(v,return_counts=True); p=c/c.sum(); return -(c*np.log2(p)).sum()
base=sum(H(y[:,j]) for j in range(F))
print(f"{A} anchors x {F} features: static per-channel {base/8:.0f} B ({base/A/F:.2f} b/value)")
mag=np.log2(np.abs(y).mean(1)+0.5)
for K in [2,4,8]:
    edges=np.quantile(mag,np.linspace(0,1,K+1)[1:-1]); z=np.searchsorted(edges,mag)
    cond=sum(H(y[z==k,j]) for k in range(K) for j in range(F))
    print(f"K={K}: H(z) {H(z)/8:.0f} B + sum H(y|z) {cond/8:.0f} B = {(H(z)+cond)/8:.0f} B ({(H(z)+cond)/base-1:+.1%}; tables not counted)")
# per-channel scale side info ideal: Laplacian with per-anchor scale (oracle)
