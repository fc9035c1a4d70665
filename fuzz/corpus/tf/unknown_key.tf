colour: red
0 0 0 0 0
