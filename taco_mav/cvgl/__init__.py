"""Cross-view geo-localisation: the satellite map service and the matchers behind one protocol."""
