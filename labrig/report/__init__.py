"""Reports: matplotlib figures (Agg backend, PNG files) for the analysis stages.

``analyse_plots`` draws the figures of ``labrig analyse``: every edge with its
first-order fit, steady speed against voltage with the fitted line and deadband,
and the paper's Km = w/V against amplitude.
"""
