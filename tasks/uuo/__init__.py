"""UUO motion capture (Milef, Keyser, Kong, SIGGRAPH 2024): unlabelled markers stuck anywhere on the body and a
monocular body prior -> marker labels, body pose and shape. One module per stage of the paper; each stage's task is
a pure function of its input arrays and its config."""
