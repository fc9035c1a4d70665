# A thin, steep feature: opaque only on 2 % of the range (an iso-surface
# of a smooth field). docs/sampling.md, "Pre-integration".
0.47 1 1 1 0
0.48 1 0.85 0.6 0.8
0.49 1 1 1 0
