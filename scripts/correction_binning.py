"""The self-induced correction's memory modes, binned coarser: how far the kernel moves.

A NumPy model of `weights_by_quadrature` (nodes/flow/src/self_induced.rs): the same
Roma-Peskin and trilinear spectra, log-spaced radii and Fibonacci directions, component x,
for a grid row's spacings in wall units. It compares the kernel sum_k w_k exp(-2 lambda_k s)
of the binned modes with the unbinned sum over every quadrature point, pointwise over
s = 0.1..1e4 t+ and for a constant force's response (its integral to 50, 150, 2000 t+):
the split in 1/lambda the code uses (p = 1 keeps weight and integral) and Lagrange weights
in ln lambda (p = 3, 5). docs/history/two-way-cost.md, "Fewer memory modes".

    python3 scripts/correction_binning.py      # a few minutes
"""
import numpy as np
def rp(r):
    a=np.abs(r); out=np.zeros_like(a)
    m1=a<=0.5; out[m1]=(1+np.sqrt(1-3*a[m1]**2))/3
    m2=(a>0.5)&(a<=1.5); b=1-a[m2]; out[m2]=(5-3*a[m2]-np.sqrt(np.maximum(1-3*b*b,0)))/6
    return out
n=600; hh=3/n; rr=-1.5+(np.arange(n)+0.5)*hh
def spec(theta):
    t=np.abs(theta)
    ft=(rp(rr)[None,:]*np.cos(t[:,None]*rr[None,:])*hh).sum(1)
    x=0.5*t; s=np.where(x<1e-8,1.0,np.sin(x)/np.where(x<1e-8,1,x))
    return ft*s*s
def points(d):
    d=np.array(d)
    kmax=np.pi*np.sqrt((1/d**2).sum()); kmin=1e-5/d.max(); nr=400; hr=np.log(kmax/kmin)/nr
    g=np.pi*(3-np.sqrt(5)); nd=800
    i=np.arange(nd); z=1-2*(i+0.5)/nd; r=np.sqrt(1-z*z); ph=g*i
    dirs=np.stack([r*np.cos(ph),r*np.sin(ph),z],1); dom=4*np.pi/nd
    lam=[];c=[]
    for ir in range(nr):
        k=np.exp(np.log(kmin)+(ir+0.5)*hr)
        th=k*dirs*d[None,:]
        ok=np.all(np.abs(th)<=np.pi,1); th=th[ok]
        s=spec(th[:,0])*spec(th[:,1])*spec(th[:,2])
        kt=2*np.sin(0.5*th)/d[None,:]; q2=(kt**2).sum(1)
        dv=k*k*(k*hr)*dom/(2*np.pi)**3
        ca=s*(1-kt[:,0]**2/q2)*dv
        lam.append(0.5*q2); c.append(ca)
    return np.concatenate(lam),np.concatenate(c)
def binned(lam,c,h,lnmin=np.log(1e-8),lnmax=np.log(1e2)):
    M=int(round((lnmax-lnmin)/h))+1
    L=np.exp(lnmin+h*np.arange(M)); w=np.zeros(M)
    x=(np.log(lam)-lnmin)/h
    for li,ci,xi in zip(lam,c,x):
        if xi<=0: m,f=0,0.0
        elif xi>=M-1: m,f=M-2,1.0
        else:
            m=int(xi); lo,hi=L[m],L[m+1]; f=(1/lo-1/li)/(1/lo-1/hi)
        w[m]+=ci*(1-f); w[m+1]+=ci*f
    return L,w


def lagr(lam,c,h,p,lnmin=np.log(1e-8),lnmax=np.log(1e2)):
    M=int(round((lnmax-lnmin)/h))+1
    L=np.exp(lnmin+h*np.arange(M)); w=np.zeros(M)
    x=(np.log(lam)-lnmin)/h
    for ci,xi in zip(c,x):
        # nodes: p+1 nearest, window clamped to [0,M-1]
        m0=int(np.floor(xi))-(p-1)//2
        m0=min(max(m0,0),M-1-p)
        nodes=np.arange(m0,m0+p+1)
        for j in nodes:
            lj=np.prod([(xi-k)/(j-k) for k in nodes if k!=j])
            w[j]+=ci*lj
    return L,w
for d in ([9.8,1.0,4.9],[9.8,0.1,4.9],[29.,3.,9.8]):
    lam,c=points(d)
    s=np.logspace(-1,4,80)
    exact=np.array([(c*np.exp(-2*lam*t)).sum() for t in s])
    for h,p in [(0.5,'split'),(1.0,'split'),(1.5,'split'),(1.0,3),(1.5,3),(1.5,5)]:
        L,w=binned(lam,c,h) if p=='split' else lagr(lam,c,h,p)
        K=np.array([(w*np.exp(-2*L*t)).sum() for t in s])
        err=K/exact-1
        T=np.array([50,150,2000])
        R=np.array([(w*(1-np.exp(-2*L*t))/(2*L)).sum() for t in T]); Re=np.array([(c*(1-np.exp(-2*lam*t))/(2*lam)).sum() for t in T])
        print(d,f"h={h} p={p} modes {len(L)} worst pointwise {np.abs(err).max():.2e}; step {np.abs(R/Re-1).max():.2e}; neg weights {np.sum(w<0)}")
