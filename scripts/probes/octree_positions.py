#!/usr/bin/env python3
"""Position coding probe (docs/codec.md, "What would pay next": octree position coding).

Ideal adaptive code lengths of a scene's grid points under two models, per point:
the Morton deltas' bit length (adaptive counts) plus its raw bits — what the format codes — and a
breadth-first octree whose child-occupancy bits are coded with adaptive binary counts in a context
of (depth near the leaves, occupied face neighbours of the parent among 6, child index, siblings
set so far).

    gscodec decode FILE.gsc -o FILE.ply
    python3 scripts/probes/octree_positions.py FILE.ply:BITS ...

BITS is the file's position grid bits (`encode --report`'s `position_bits`); the points are put
back on a grid of that many bits over their bounds. Numbers are estimates (no table costs).
"""
import sys, math

import numpy as np
from collections import defaultdict
def read_ply(p):
    f=open(p,'rb'); props=[]; n=0
    while True:
        l=f.readline().decode().strip()
        if l.startswith('element vertex'): n=int(l.split()[2])
        if l.startswith('property'): props.append((l.split()[1], l.split()[2]))
        if l=='end_header': break
    dt=np.dtype([(nm, {'float':'<f4','uchar':'u1','double':'<f8'}[t]) for t,nm in props])
    return np.frombuffer(f.read(n*dt.itemsize), dtype=dt, count=n)
def grid_coords(v,bits):
    out=[]
    for a in 'xyz':
        x=v[a].astype(np.float64); step=(x.max()-x.min())/(2**bits-1)
        out.append(np.round((x-x.min())/step).astype(np.int64))
    return np.stack(out,1)
def morton(c,bits):
    m=np.zeros(len(c),dtype=np.uint64)
    for b in range(bits):
        for a in range(3):
            m|=((c[:,a]>>b)&1).astype(np.uint64)<<np.uint64(3*b+(2-a))
    return m
class Bin:
    def __init__(s): s.c=defaultdict(lambda:[0.5,0.5]); s.bits=0.0
    def code(s,ctx,b):
        c=s.c[ctx]; s.bits-=math.log2(c[b]/(c[0]+c[1])); c[b]+=1
for arg in sys.argv[1:]:
    p,gb=arg.split(':'); v=read_ply(p); c=grid_coords(v,int(gb))
    c=np.unique(c,axis=0)  # duplicates
    bits=int(max(1,int(c.max()).bit_length()))
    n=len(c)
    m=np.sort(morton(c,bits))
    # Morton delta: length adaptive (255-ary approx with counts), raw bits
    d=np.diff(np.concatenate([[0],m.astype(np.int64)]))
    L=np.array([int(x).bit_length() for x in d])
    cnt=defaultdict(lambda:0.5); tot=0.5*(3*bits+1); md=0.0
    for l in L:
        md-=math.log2(cnt[l]/tot); cnt[l]+=1; tot+=1
        md+=max(l-1,0)
    # static ideal (what a stored histogram gets): entropy of L + raw
    vals,counts=np.unique(L,return_counts=True); H=-(counts*np.log2(counts/n)).sum()+np.maximum(L-1,0).sum()
    # octree breadth-first with neighbour context
    enc=Bin(); level_nodes={(0,0,0)}
    for depth in range(bits):
        shift=bits-depth-1
        occ=set(map(tuple,(c>>shift)))
        occ_parent=level_nodes
        # children per parent
        ch=defaultdict(list)
        for (x,y,z) in occ: ch[(x>>1,y>>1,z>>1)].append(((x&1)<<2)|((y&1)<<1)|(z&1))
        for par in sorted(occ_parent):
            px,py,pz=par
            nb=sum(((px+dx,py+dy,pz+dz) in occ_parent) for dx,dy,dz in [(1,0,0),(-1,0,0),(0,1,0),(0,-1,0),(0,0,1),(0,0,-1)])
            kids=set(ch[par]); sofar=0
            for k in range(8):
                b=1 if k in kids else 0
                # last child forced if none so far
                if k==7 and sofar==0: break
                enc.code((min(depth,bits-1) if depth>bits-6 else -1, nb, k, min(sofar,3)), b); sofar+=b
        level_nodes=occ
    print(f"{p}: {n} points on {bits}-bit grid: morton adaptive {md/n:.2f} b/pt, static {H/n:.2f}; octree {enc.bits/n:.2f} b/pt")
