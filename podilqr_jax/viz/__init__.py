"""Plots and animations of a solve."""
