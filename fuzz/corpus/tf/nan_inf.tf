0 0 0 0 nan
1 inf 1 1 1
