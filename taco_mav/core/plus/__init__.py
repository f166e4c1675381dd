"""taco+ (issue 7 and after, beyond the paper): `mode.PlusMode`, the Localiser's mode that owns the parts in this
package (noise model, search, lock, held answers, stops, safety guard, camera speed, GNSS update)."""
