"""DeepMoCap (Chatzitofis et al., Sensors 2019): IR-depth views -> reflector masks, colorized depth and 3D flow ->
two-stream FCN heatmaps -> labelled 2D reflectors -> fused 3D markers -> tracks -> calibrated skeleton and poses.
One module per stage of the paper; each stage's task is a pure function of its input arrays and its config."""
