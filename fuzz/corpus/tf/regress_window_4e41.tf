range: window 401e39 40
0 0 0 0 0
