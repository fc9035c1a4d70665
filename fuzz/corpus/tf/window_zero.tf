range: window 0 40
0 0 0 0 0
