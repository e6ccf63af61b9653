"""Vehicle models as pure functions with their parameters as data (in the style of CommonRoad's).

- :mod:`plm_highway.vehicle.models`: the table (``VEHICLE_MODELS``, ``vehicle_model(name)``) that the
  env, sim2real and the estimator pick models from: name -> step, sensors, derivatives, parameters.

- :mod:`plm_highway.vehicle.kinematic`: the simulator's model, highway-env's kinematic bicycle
  (``Vehicle.step``), bit for bit; a step function and vectorised rollouts over time and batches.
- :mod:`plm_highway.vehicle.single_track`: a dynamic single-track model with linear tires (the
  physics the kinematic bicycle leaves out), with a fine RK4 step and a replay-rate integrator.
- :mod:`plm_highway.vehicle.tires`: the same model with magic-formula tires that saturate at a friction
  limit, and a road bank (sim2real's tire effects; the table's ``saturating`` car).
- :mod:`plm_highway.vehicle.paper_units`: the PLM-Net papers' steering unit (450 deg of steering
  wheel) and the 12:1 steering ratio that turns it into front-wheel radians (the papers' car's, 12.16:1).
"""
