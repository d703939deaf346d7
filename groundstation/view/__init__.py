"""The flight seen in rerun: live during a flight (--view, --view-save FILE.rrd) or replayed from its logs
(`cfstack view LOGDIR`). Takes in TickFrames, the world and the plan; gives out a rerun recording.
May import: groundstation.tickframe, groundstation.logread, model, rerun (the rerun-sdk package)."""
