"""Dense capture with a checkerboard suit (Chen, Park, Macit, Kavan 2021): a suit printed with coded checkerboard
squares, many grey cameras -> uniquely labelled corners per frame -> triangulated 3D, holes filled by a
spatio-temporal Laplacian solve. One module per stage of the paper; each stage's task is a pure function of its
input arrays and its config."""
