"""Un-indexed marker tracking after Porter (2012): separate a rope from the body,
track its markers through gaps, repair the gaps."""
