units: data
5 0 0 0 0
-5 1 1 1 1
