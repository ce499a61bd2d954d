"""Training losses: the darknet-style YOLOv3 loss (``slimseg.losses.yolov3``)."""
