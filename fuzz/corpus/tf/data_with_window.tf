units: data
range: window 400 40
0 0 0 0 0
1 1 1 1 1
