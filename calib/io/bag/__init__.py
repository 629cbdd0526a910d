"""calib.io.bag: ROS recordings (ROS 1 ``.bag``, ROS 2 sqlite3 and MCAP bags) read into
:class:`calib.Measurements` without ROS (:func:`calib.io.bag.reader.read_bag`)."""
