"""The chapter-7 calibration as the runtime sees it: the calibration file (format, atomic writes), the schema
files are read against (`file_schema`, also the calibration datasets'), the checks a calibration must
pass before a node uses it (`calibration_checks`) and the bearing corrections it describes
(`bearing_correction`, eq. 7.19 and 7.25).
"""
