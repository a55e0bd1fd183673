"""The bus contract both sides share: frame codecs, the CiA 402 table, the EDS files, the DBC."""
