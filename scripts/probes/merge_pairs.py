#!/usr/bin/env python3
"""Merging probe (docs/codec.md §14): merge the closest pairs of Gaussians into one before the
RD search, to see whether fewer, merged Gaussians code smaller at equal PSNR.

Pairs: each Gaussian's nearest other by the smaller of the two Mahalanobis distances of their
centres, plus CW times the squared difference of their SH DC and the absolute log ratio of their
volumes; the lowest-cost disjoint pairs, FRAC of the Gaussians' count. A pair becomes one
Gaussian by moment matching (weights opacity × volume: mean, covariance), its opacity keeping
the pair's opacity × volume (between the larger opacity and 1 − (1 − a)(1 − b)), its SH the
average weighted by opacity × volume^(2/3). numpy only; brute-force neighbours (about a minute
for 20k Gaussians).

    python3 scripts/probes/merge_pairs.py IN.ply OUT.ply FRAC [CW]
    gscodec encode OUT.ply -o OUT.gsc --lambda L && gscodec eval OUT.gsc --reference IN.ply --orbit 8
"""
import numpy as np, sys
def readply(p):
    f=open(p,'rb'); hdr=b''
    while True:
        l=f.readline(); hdr+=l
        if l.strip()==b'end_header': break
    lines=hdr.split(b'\n')
    props=[l.split()[-1].decode() for l in lines if l.startswith(b'property')]
    n=int([l for l in lines if l.startswith(b'element vertex')][0].split()[-1])
    a=np.frombuffer(f.read(), dtype='<f4', count=n*len(props)).reshape(n,len(props)).copy()
    return props,a
def writeply(p,props,a):
    with open(p,'wb') as f:
        f.write(b'ply\nformat binary_little_endian 1.0\nelement vertex %d\n'%len(a))
        for q in props: f.write(b'property float %s\n'%q.encode())
        f.write(b'end_header\n'); f.write(a.astype('<f4').tobytes())
props,a=readply(sys.argv[1]); out=sys.argv[2]; frac=float(sys.argv[3]); cw=float(sys.argv[4]) if len(sys.argv)>4 else 4.0
P={p:i for i,p in enumerate(props)}
n=len(a)
mu=a[:,[P['x'],P['y'],P['z']]].astype(np.float64)
ls=a[:,[P['scale_0'],P['scale_1'],P['scale_2']]].astype(np.float64)
q=a[:,[P['rot_0'],P['rot_1'],P['rot_2'],P['rot_3']]].astype(np.float64)
q/=np.linalg.norm(q,axis=1,keepdims=True)
op=1/(1+np.exp(-a[:,P['opacity']].astype(np.float64)))
dc=a[:,[P['f_dc_0'],P['f_dc_1'],P['f_dc_2']]].astype(np.float64)
w,x,y,z=q.T
R=np.stack([1-2*(y*y+z*z),2*(x*y-w*z),2*(x*z+w*y),
            2*(x*y+w*z),1-2*(x*x+z*z),2*(y*z-w*x),
            2*(x*z-w*y),2*(y*z+w*x),1-2*(x*x+y*y)],1).reshape(n,3,3)
S=np.exp(ls)
Sig=np.einsum('nij,nj,nkj->nik',R,S*S,R)
vol=np.prod(S,1)
# nearest neighbour by symmetric Mahalanobis distance, brute force in blocks
best=np.full(n,np.inf); arg=np.full(n,-1)
Sinv=np.linalg.inv(Sig+1e-12*np.eye(3))
for s in range(0,n,512):
    e=min(n,s+512)
    d=mu[None,:,:]-mu[s:e,None,:]            # (b,n,3)
    m1=np.einsum('bni,bij,bnj->bn',d,Sinv[s:e],d)
    m2=np.einsum('bni,nij,bnj->bn',d,Sinv,d)
    cost=np.minimum(m1,m2)+cw*np.sum((dc[None,:,:]-dc[s:e,None,:])**2,2)
    # size similarity: log volume ratio
    cost+= np.abs(np.log(vol[None,:]/vol[s:e,None]))
    for k in range(e-s): cost[k,s+k]=np.inf
    j=np.argmin(cost,1); best[s:e]=cost[np.arange(e-s),j]; arg[s:e]=j
order=np.argsort(best)
used=np.zeros(n,bool); pairs=[]
target=int(frac*n)
for i in order:
    j=arg[i]
    if used[i] or used[j]: continue
    used[i]=used[j]=True; pairs.append((i,j))
    if len(pairs)>=target: break
print('pairs',len(pairs),'cost at cut',best[pairs[-1][0]] if pairs else None)
keep=np.ones(n,bool); new=a.copy()
rest=[P[p] for p in props if p.startswith('f_rest_')]+[P['f_dc_0'],P['f_dc_1'],P['f_dc_2']]
for i,j in pairs:
    wi=op[i]*vol[i]; wj=op[j]*vol[j]; W=wi+wj
    m=(wi*mu[i]+wj*mu[j])/W
    di=mu[i]-m; dj=mu[j]-m
    C=(wi*(Sig[i]+np.outer(di,di))+wj*(Sig[j]+np.outer(dj,dj)))/W
    ev,V=np.linalg.eigh(C)
    if np.linalg.det(V)<0: V[:,0]*=-1
    sc=np.sqrt(np.maximum(ev,1e-20))
    vm=np.prod(sc)
    o=min(0.995,(op[i]*vol[i]+op[j]*vol[j])/vm)
    o=max(o,max(op[i],op[j]))
    o=min(o,1-(1-op[i])*(1-op[j]))
    # rotation matrix -> quaternion (w,x,y,z)
    Rm=V; tr=np.trace(Rm)
    qw=np.sqrt(max(0,1+tr))/2; qx=np.sqrt(max(0,1+Rm[0,0]-Rm[1,1]-Rm[2,2]))/2
    qy=np.sqrt(max(0,1-Rm[0,0]+Rm[1,1]-Rm[2,2]))/2; qz=np.sqrt(max(0,1-Rm[0,0]-Rm[1,1]+Rm[2,2]))/2
    qx=np.copysign(qx,Rm[2,1]-Rm[1,2]); qy=np.copysign(qy,Rm[0,2]-Rm[2,0]); qz=np.copysign(qz,Rm[1,0]-Rm[0,1])
    new[i,[P['x'],P['y'],P['z']]]=m
    new[i,[P['scale_0'],P['scale_1'],P['scale_2']]]=np.log(sc)
    new[i,[P['rot_0'],P['rot_1'],P['rot_2'],P['rot_3']]]=[qw,qx,qy,qz]
    new[i,P['opacity']]=np.log(o/(1-o))
    cwi=op[i]*vol[i]**(2/3); cwj=op[j]*vol[j]**(2/3)
    new[i,rest]=(cwi*a[i,rest]+cwj*a[j,rest])/(cwi+cwj)
    keep[j]=False
writeply(out,props,new[keep])
print('wrote',keep.sum())
