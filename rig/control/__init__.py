"""Force tracking beyond open loop: iterative learning across trials (``ilc``), load-cell
feedback in the 500 Hz loop (``feedback``) and the learned-feedforward record (``records``)."""
