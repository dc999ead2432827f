"""Model-based coding's stream format (:mod:`facesculpt.coding.fsc`), shared by the offline coder
(:mod:`facesculpt.app.coding`), the live encoder and the decoder node. It sits above the messages
and the shared geometry (its basis is interpolated over the mesh) and below the nodes."""
