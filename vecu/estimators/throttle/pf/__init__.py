"""The production throttle estimator, a particle filter with Kalman stretches, by role: model
(eq. 3 as class matrices, the reported estimate), state (the named state record, the particle
sets), update (the particle step), resample, kalman_stretch, recursion (one tick, written once
for both kernel backends) and filter (ThrottleParticleFilter, make_production_estimator)."""
