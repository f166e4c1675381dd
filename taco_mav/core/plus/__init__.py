"""taco+, beyond the paper: `estimator.make_plus` composes the Localiser's estimator from the parts in this package
(filter, trigger, fix policy, GNSS update, reported accuracy, aiding, and what they share: the lock, held answers,
stops, the safety guard, the camera speed's scale error, the noise factors)."""
