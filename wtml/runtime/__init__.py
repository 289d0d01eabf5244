"""Device runtime: ONNX export, onnxruntime sessions, the predict entry."""
