"""Data-driven virtual sensors (DVS): neural networks trained on simulated experiments, the
feed-forward ``net1``, ``ffnn`` and ``dtdnn`` and the recurrent ``net2`` (NARX) and ``lrn``, with
their MATLAB-style training (``trainbr``, or Adam)."""
