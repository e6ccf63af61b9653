"""The models a recording is replayed through: the steering chain, the effect library and its terms, the channels' filters, and recordings made from richer physics."""
