from textile_fenicsx.cli.main import main

raise SystemExit(main())
