# Independent ISO 230-2:2014 evaluation of encoder-vs-setpoint.csv with exact
# decimal arithmetic (Python stdlib only, no shared code with the Rust crate).
# Its output is pasted into tests/metrology_iso230_2.rs as the expected values.
# Run: python3 tests/data/iso230-2/reference_iso230_2.py
import csv
from decimal import Decimal, getcontext
getcontext().prec = 50
import os
rows = list(csv.DictReader(open(os.path.join(os.path.dirname(os.path.abspath(__file__)), 'encoder-vs-setpoint.csv'))))
targets = sorted({Decimal(r['target_mm']) for r in rows})
dev = {}  # (target, dir) -> list of deviations in um
for r in rows:
    t = Decimal(r['target_mm']); d = 'up' if r['direction']=='forward' else 'down'
    dev.setdefault((t,d), []).append((Decimal(r['measured_mm']) - t) * 1000)
def mean(v): return sum(v)/len(v)
def s(v):
    m = mean(v); return (sum((x-m)**2 for x in v)/(len(v)-1)).sqrt()
res = {}
xu=[];xd=[];su=[];sd=[];B=[];Ri=[];xm=[]
for t in targets:
    u = dev[(t,'up')]; d = dev[(t,'down')]
    a=mean(u); b=mean(d); c=s(u); e=s(d)
    xu.append(a); xd.append(b); su.append(c); sd.append(e)
    B.append(a-b); Ri.append(max(2*c+2*e+abs(a-b), 4*c, 4*e)); xm.append((a+b)/2)
    print(f"target {t} mm: xu={a:.10f} xd={b:.10f} su={c:.12f} sd={e:.12f} B={a-b:.10f} R={Ri[-1]:.12f} xbar={(a+b)/2:.10f}")
out = dict(
 B=max(abs(x) for x in B), Bmean=mean(B),
 Rup=max(4*x for x in su), Rdown=max(4*x for x in sd), R=max(Ri),
 Eup=max(xu)-min(xu), Edown=max(xd)-min(xd), E=max(xu+xd)-min(xu+xd),
 M=max(xm)-min(xm),
 Aup=max(a+2*c for a,c in zip(xu,su))-min(a-2*c for a,c in zip(xu,su)),
 Adown=max(a+2*c for a,c in zip(xd,sd))-min(a-2*c for a,c in zip(xd,sd)),
 A=max([a+2*c for a,c in zip(xu,su)]+[a+2*c for a,c in zip(xd,sd)])-min([a-2*c for a,c in zip(xu,su)]+[a-2*c for a,c in zip(xd,sd)]),
)
for k,v in out.items(): print(f"{k} = {v:.12f} um")
