"""Pure estimators: complementary attitude filter and the 7-state EKF (no pydrake)."""
