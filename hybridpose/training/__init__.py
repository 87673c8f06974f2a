"""Making and judging the CNN regressors — what a user who only predicts never imports: training
(:mod:`.train`, its data, steps and the twin verifier's training), evaluation on held-out sets
(:mod:`.evaluate`, :mod:`.compare`), Grad-CAM pictures (:mod:`.gradcam`) and 8-bit quantisation
(:mod:`.quantize`). The run-time backends stay in :mod:`hybridpose.regressors`."""
