"""eha: model-based prognostics of flapper-nozzle servo-valve electro-hydraulic actuators."""

__version__ = "0.1.0"
