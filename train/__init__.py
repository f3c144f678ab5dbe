"""Thin entry point of the training job: ``python -m train CONFIG`` == ``prt train CONFIG``."""
