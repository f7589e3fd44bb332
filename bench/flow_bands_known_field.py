#!/usr/bin/env python3
# Banded vs whole DIS flow against known smooth displacement fields (issue 17 item 7): the
# CPU flow warper splits each flow into work_rows/160 bands of rows, each estimated on its rows
# +- 32 rows (src/stitch/warp/flow_warper_cpu.cpp). This replica (same OpenCV DIS presets: medium
# quality = PRESET_FAST at 285x541, fine = PRESET_MEDIUM at 570x1081) prints the median/p95
# endpoint error of both against the truth. Photos from ../shared (skipped when missing) and the
# repository. usage: /usr/bin/python3 bench/flow_bands_known_field.py
import os
import cv2, numpy as np
cv2.setNumThreads(1)
REPO = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..') + '/'
SHARED = os.environ.get('STITCH_SHARED_DATA', REPO + '../shared/data') + '/'
imgs=[SHARED + 'images/eadcat_apap_demo/demo2/boat03.jpg',SHARED + 'images/eadcat_apap_demo/demo5/P1010517.JPG',SHARED + 'images/udis2_carpark_dhw/input1.jpg',REPO + 'data/photos/boat1_1600.jpg']
def dis(q):
    d=cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST if q=='medium' else cv2.DISOPTICAL_FLOW_PRESET_MEDIUM); d.setUseSpatialPropagation(True); return d
def banded(a,b,q,T,M=32):
    H=a.shape[0]; out=np.zeros(a.shape+(2,),np.float32)
    for i in range(T):
        y0=H*i//T; y1=H*(i+1)//T; s0=max(0,y0-M); s1=min(H,y1+M)
        f=dis(q).calc(np.ascontiguousarray(a[s0:s1]),np.ascontiguousarray(b[s0:s1]),None)
        f[...,0]=np.clip(f[...,0], -np.arange(a.shape[1])[None,:], a.shape[1]-1-np.arange(a.shape[1])[None,:])
        out[y0:y1]=f[y0-s0:y1-s0]
    return out
rng=np.random.default_rng(1)
for q,(W,H) in [('medium',(285,541)),('fine',(570,1081))]:
  for path in imgs:
    img=cv2.imread(path,0)
    if img is None:
        continue
    s=1080.0/img.shape[0]*(1 if q=='fine' else 0.5)*1.0
    img=cv2.resize(img,None,fx=s*1.2,fy=s*1.2,interpolation=cv2.INTER_AREA)
    a=img[:H,:W].copy() if img.shape[1]>=W else None
    if a is None: continue
    for amp in [2.0,6.0]:
        yy,xx=np.mgrid[0:H,0:W].astype(np.float32)
        u=amp*np.sin(xx/W*2*np.pi*0.7+0.3)*np.cos(yy/H*2*np.pi*0.9); v=0.5*amp*np.cos(xx/W*2*np.pi*0.5)*np.sin(yy/H*2*np.pi*1.3+1)
        # b(x+u) = a(x)  => b(p) = a(p - flow) approx; build b by sampling a at p - (u,v)
        b=cv2.remap(a, xx-u, yy-v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        truth=np.dstack([u,v])
        inner=(slice(8,H-8),slice(8,W-8))
        full=dis(q).calc(a,b,None)
        T=max(1,H//160)
        bd=banded(a,b,q,T)
        e=lambda f: np.hypot(*(f-truth)[inner].transpose(2,0,1))
        ef,eb=e(full),e(bd); d=np.hypot(*(full-bd)[inner].transpose(2,0,1))
        print(f'{q} {path.split("/")[-1]} amp {amp}: vs truth untiled med {np.median(ef):.3f} p95 {np.percentile(ef,95):.2f} | {T} bands med {np.median(eb):.3f} p95 {np.percentile(eb,95):.2f} | bands vs untiled med {np.median(d):.3f}', flush=True)
