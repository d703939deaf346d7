"""A flightsim-compatible package for user code: `flightsim.world.World` and
`flightsim.crazyflie_params.quad_params`, backed by cfstack's world model and the vehicle in use.

Takes in: nothing at import. Gives out: the modules below.
"""
