# bone in HU
units: data
-200 0 0 0 0
300, 1, 1, 1, 0.5
1300 1 1 1 1  # cortex
