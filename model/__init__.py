"""cfstack model: what every side agrees the flying setup is.

Holds: world maps (model.world, one validator for every command), vehicle and mocap-room parameters
(model.vehicle, model/params/vehicles, model/params/mocap), radio profiles (model.radio,
model/params/radio), frames and rotations (model.frames: ENU world, FLU body, quaternions w x y z),
the versioned-TOML loader and writer (model.config) and the errors a user can cause (model.errors).
Takes in: world JSON and parameter TOML files.
Gives out: checked, immutable descriptions in SI units; one-line errors naming the file and field.
May import: nothing of cfstack (numpy, scipy only). Every other package may import it.
"""
