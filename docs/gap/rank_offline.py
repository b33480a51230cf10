"""Re-ranks gap-bench candidates offline from `bench.json` under other score variants (no\nrefit): `python3 docs/gap/rank_offline.py out/bench.json A,B,C,N,S [g]` (session 7 study,\ndocs/results.md)."""
import json, math, sys
TAU=2*math.pi
def gaussian_ll(rss, sig, variance, floor=0.5):
    """Held-out Gaussian log-likelihood per channel, the variance chosen by `variance(rt, nt,
    re, ne)` (training / held-out RSS and counts) and floored at `floor` times the noise's."""
    ll = 0
    for (rt, nt, re, ne), s in zip(rss, sig):
        var = max(variance(rt, nt, re, ne), floor * s * s)
        ll -= 0.5 * ne * math.log(TAU * var) + 0.5 * re / var
    return ll
def ll_train_var(rss, sig):
    return gaussian_ll(rss, sig, lambda rt, nt, re, ne: rt / max(nt, 1))
def ll_test_var(rss, sig):
    return gaussian_ll(rss, sig, lambda rt, nt, re, ne: re / max(ne, 1))
def ll_pool(rss, sig):
    return gaussian_ll(rss, sig, lambda rt, nt, re, ne: (rt + re) / max(nt + ne, 1))
def ll_noise(rss, sig):
    return sum(-0.5 * re / (s * s) for (rt, nt, re, ne), s in zip(rss, sig))
def ll_2fold_approx(rss, sig):
    # Symmetric: held-out scored with the training variance plus training scored with the
    # held-out variance (parameters fitted on training, so optimistic there).
    swapped = [(re, ne, rt, nt) for rt, nt, re, ne in rss]
    return ll_train_var(rss, sig) + ll_train_var(swapped, sig)
SCORES={'A':ll_train_var,'B':ll_test_var,'C':ll_pool,'N':ll_noise,'S':ll_2fold_approx}
def evaluate(o, fn):
    sig=o['sigma']; nom=o['nominal_rss']
    ntr=sum(r[1] for r in nom)
    pen=0.5*math.log(max(ntr,2))
    base_A=ll_train_var(nom,sig)
    nb=fn(nom,sig)
    out=[]
    for c in o['candidates']:
        if '+' in c['effect']: continue
        la=ll_train_var(c['rss'],sig)
        k=round((la-base_A-c['score'])/pen) if math.isfinite(c['score']) else 0
        s=fn(c['rss'],sig)-k*pen-nb
        out.append((s,c['effect'],c['gap'][2],k))
    out.sort(key=lambda t:-t[0])
    return out
def main(path, keys, guard=False, verbose=False):
    d=json.load(open(path))
    for key in keys:
        fn=SCORES[key]
        hit=tot=t3=0; misses=[]
        for o in d:
            L=o['label']
            if L['kind']!='single' or L['ratio']<2: continue
            r=evaluate(o,fn)
            if guard:
                r=sorted(r,key=lambda t:(t[2]<0 and True, -t[0]))
            tot+=1
            if r and r[0][1]==L['effects'][0]: hit+=1
            else: misses.append((o['name'],[(e,round(s,1),round(sh,2)) for s,e,sh,k in r[:3]]))
            if any(e==L['effects'][0] for s,e,sh,k in r[:3]): t3+=1
        print(key,'guard' if guard else '', f"top1 {hit}/{tot} top3 {t3}/{tot}")
        if verbose:
            for m in misses: print('   ',m)
if __name__=='__main__':
    main(sys.argv[1], sys.argv[2].split(','), guard=len(sys.argv)>3 and sys.argv[3]=='g', verbose=True)
