#!/usr/bin/env python3
"""Lists functions longer than a limit: scripts/function_lengths.py DIR [LIMIT=120].

A brace-matching heuristic over C++ sources (comments, strings and raw
strings blanked first): a brace block whose head ends like a function
signature, outside another function, counts as a function; lambdas and
blocks inside a function count towards it. Prints "LINES FILE:LINE NAME",
longest first; exits 0 either way (a report, not a check)."""
import re,sys,os
def strip(src):
    out=[];i=0;n=len(src)
    while i<n:
        c=src[i]
        if src.startswith('//',i):
            j=src.find('\n',i); j=n if j<0 else j; i=j; continue
        if src.startswith('/*',i):
            j=src.find('*/',i+2); seg=src[i:j+2]; out.append('\n'*seg.count('\n')); i=j+2; continue
        if src.startswith('R"',i):
            m=re.match(r'R"([^(]*)\(',src[i:]); d=m.group(1); j=src.find(')'+d+'"',i); seg=src[i:j+len(d)+2]; out.append('""'+'\n'*seg.count('\n')); i=j+len(d)+2; continue
        if c=='"' or c=="'":
            j=i+1
            while j<n and src[j]!=c:
                j+= 2 if src[j]=='\\' else 1
            out.append(c+c); i=j+1; continue
        out.append(c); i+=1
    return ''.join(out)
res=[]
for root,_,files in os.walk(sys.argv[1]):
    for f in files:
        if not f.endswith(('.cc','.h')): continue
        p=os.path.join(root,f); s=strip(open(p).read())
        lines=s.split('\n')
        stack=[]  # entries: (kind,startline,name)
        for ln,line in enumerate(lines,1):
            for k,ch in enumerate(line):
                if ch=='{':
                    head=line[:k]
                    # look back up to 3 lines for context
                    ctx=' '.join(lines[max(0,ln-4):ln-1])+' '+head
                    if re.search(r'\b(namespace|class|struct|enum|union)\b[^;{}()]*$',ctx) and not re.search(r'\)\s*(const)?\s*(noexcept)?\s*(override)?\s*$',head.strip()):
                        kind='scope'
                    elif any(e[0]=='func' for e in stack): kind='inner'
                    elif re.search(r'\)\s*(const|noexcept|override|final|->\s*[\w:<>]+|\s)*$',head) or (head.strip()=='' and re.search(r'\)\s*(const)?\s*(noexcept)?\s*(override)?\s*$',lines[ln-2] if ln>1 else '')) or re.search(r':\s*\w+\(.*\)\s*$',head):
                        kind='func'
                    else: kind='inner' if stack and stack[-1][0]!='scope' else 'other'
                    name=re.findall(r'([\w:~]+)\s*\(',ctx)
                    stack.append((kind,ln,name[0] if name else '?'))
                elif ch=='}':
                    if stack:
                        kind,st,name=stack.pop()
                        if kind=='func': res.append((ln-st+1,p,st,name))
res.sort(reverse=True)
lim=int(sys.argv[2]) if len(sys.argv)>2 else 120
for r in res:
    if r[0]>lim: print(r[0],r[1]+':'+str(r[2]),r[3])
