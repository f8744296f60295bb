"""Plotting (layer 5): figures from arrays and results; never fits, samples or reads run folders."""
