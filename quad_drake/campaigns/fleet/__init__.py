"""Fleet mode: N runs of a scenario flown in one Diagram (its recorder, the batch runner and the
runs' streamed summaries), the estimators' fleet forms and the compiled kernels."""
