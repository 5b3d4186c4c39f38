"""The closed loop that flies a batch: the numpy reference step (:mod:`.simulate`) and the compiled
kernel (:mod:`.kernel`, :mod:`.kernel_layout`, driven by :mod:`.compiled`), on the batch of :mod:`.flight_batch`."""
