units: normalised
range: percentiles 1 99.5
reference_step: 0.5
0 0 0 0 0
0.25 1 0.5 0 0.1
0.5 1 1 0 0.4
1 1 1 1 1
